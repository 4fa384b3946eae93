"""A corner lane: each lane's map at its ends, inverted exactly, and the frame through a roundabout's entry and exit."""

from __future__ import annotations

import math

import numpy as np
import pytest
from highway_env.road.lane import CircularLane, StraightLane

import driveopt
from driveopt.sim.corner_lane import CornerLane, smoothstep
from driveopt.sim.road_frame import build_frame, ego_frame, lane_curvature


def _corner() -> tuple[StraightLane, CircularLane, CornerLane]:
    """A straight lane along +x to (40, 0) and an arc of radius 30 m starting 2 m beside its end, turned by 50 degrees;
    the corner from 12 m before the joint on the first to 8 m after it on the second."""
    a = StraightLane([0.0, 0.0], [40.0, 0.0])
    phase = math.radians(-40.0)
    centre = np.array([40.0, 2.0]) - 30.0 * np.array([math.cos(phase), math.sin(phase)])
    b = CircularLane(centre, 30.0, phase, phase + 1.5, clockwise=True)
    return a, b, CornerLane(a, 28.0, 0.0, b, -12.0, -2.0, 20.0)


def test_the_smoothstep_runs_from_zero_to_one_with_flat_ends():
    u = np.linspace(0.0, 1.0, 101)
    w = smoothstep(u)
    assert w[0] == 0.0 and w[-1] == 1.0 and np.all(np.diff(w) > 0.0)
    slope = np.gradient(w, u)
    assert abs(slope[0]) < 1e-3 and abs(slope[-1]) < 1e-3
    assert smoothstep(-1.0) == 0.0 and smoothstep(2.0) == 1.0


def test_its_map_is_each_lanes_map_at_its_ends_for_every_lateral_offset():
    a, b, corner = _corner()
    for lateral in (-3.0, 0.0, 1.5, 4.0):
        np.testing.assert_allclose(corner.position(0.0, lateral), a.position(28.0, lateral), atol=1e-9)
        np.testing.assert_allclose(corner.position(20.0, lateral), b.position(8.0, lateral - 2.0), atol=1e-9)
        np.testing.assert_allclose(corner.position(-5.0, lateral), a.position(23.0, lateral), atol=1e-9)
        np.testing.assert_allclose(corner.position(25.0, lateral), b.position(13.0, lateral - 2.0), atol=1e-9)
    assert abs(corner.heading_at(0.0) - a.heading_at(28.0)) < 1e-3
    assert abs(math.remainder(corner.heading_at(20.0) - b.heading_at(8.0), 2 * math.pi)) < 1e-3


def test_the_reference_line_is_continuous_and_turns_gradually():
    _, _, corner = _corner()
    length = np.linspace(-2.0, 22.0, 2401)
    points = np.array([corner.position(x, 0.0) for x in length])
    steps = np.hypot(*np.diff(points, axis=0).T)
    assert steps.max() < 0.015, "no jump: 0.01 m apart along it, at most 0.015 m apart in the world"
    heading = np.unwrap([corner.heading_at(x) for x in length])
    assert np.abs(np.diff(heading)).max() < math.radians(0.2)


def test_local_coordinates_invert_the_map():
    _, _, corner = _corner()
    rng = np.random.default_rng(0)
    for longitudinal, lateral in rng.uniform([-3.0, -5.0], [23.0, 5.0], size=(40, 2)):
        found = corner.local_coordinates(corner.position(longitudinal, lateral))
        np.testing.assert_allclose(found, (longitudinal, lateral), atol=1e-6)


def test_a_corner_lane_needs_a_length():
    a, b, _ = _corner()
    with pytest.raises(ValueError, match="positive length"):
        CornerLane(a, 0.0, 0.0, b, 0.0, 0.0, 0.0)


@pytest.mark.parametrize("env_id", ["roundabout-v0", "roundabout-generic-v0"])
def test_the_frame_through_a_roundabouts_entry_and_exit_is_continuous_and_keeps_its_lanes(env_id):
    env = driveopt.gym_make(env_id, config={"action": {"type": "ContinuousAction"}})
    env.reset(seed=0)
    controller = driveopt.Controller("idm")
    controller.reset(env, seed=0)
    frame, _ = ego_frame(env.unwrapped, controller.task.route)
    corners = [p for p in frame.pieces if isinstance(p.lane, CornerLane)]
    assert len(corners) == 2, "one at the ring's entry, one at its exit"
    ring = next(b for p in frame.pieces for b in p.bands if b.road == ("se", "ex"))
    for piece in corners:
        entry_or_exit = next(b for b in piece.bands if b.road != ring.road and b.num_lanes == 1)
        outer = ring.first_center + (ring.num_lanes - 1) * ring.lane_width
        assert abs(entry_or_exit.first_center - outer) < 1e-6, "the entry's and exit's lanes continue the ring's outer one"
    s = np.arange(corners[0].s_start - 5.0, corners[1].s_start + corners[1].hi, 0.1)  # into the entry, to the exit
    for d in (ring.first_center, ring.first_center + ring.lane_width):
        x, y, heading, curvature, _ = frame.to_world(s, np.full_like(s, d))
        assert np.hypot(np.diff(x), np.diff(y)).max() < 0.25, f"a jump in the map at d = {d}"
        assert np.abs(np.angle(np.exp(1j * np.diff(heading)))).max() < math.radians(1.0)
        assert np.abs(curvature).max() < 0.15
        for k in range(0, len(s), 40):
            found = frame.locate(np.array([x[k], y[k]]), near_s=s[k])
            assert found is not None and abs(found[0] - s[k]) < 1e-5 and abs(found[1] - d) < 1e-5
    env.close()


@pytest.mark.parametrize("env_id", ["roundabout-v0", "roundabout-generic-v0"])
def test_every_frame_along_the_route_has_the_same_corners(env_id):
    """Built from any road of the route (the ego on the entry, on the ring, on the exit), the frame turns at the same
    corner pieces: roundabout-generic-v0's entry and exit meet the ring's outer lane end to end at 66 degrees, which a
    frame built from the ring once took at once."""
    env = driveopt.gym_make(env_id, config={"action": {"type": "ContinuousAction"}})
    env.reset(seed=0)
    controller = driveopt.Controller("idm")
    controller.reset(env, seed=0)
    route = controller.task.route
    network = env.unwrapped.road.network
    # world points along the exit lane's centre, through the exit's corner
    exit_lane = network.graph["nx"]["nxs"][0]
    points = [np.asarray(exit_lane.position(along, 0.0)) for along in (0.0, 4.0, 8.0, 12.0)]
    laterals = []
    for road in [("ses", "se"), ("se", "ex"), ("ex", "ee"), ("ee", "nx"), ("nx", "nxs")]:
        frame = build_frame(network, road, route)
        assert sum(isinstance(p.lane, CornerLane) for p in frame.pieces) == 2, road
        exit_band = next(b for p in frame.pieces for b in p.bands if b.road == ("nx", "nxs"))
        laterals.append([frame.locate(point)[1] - exit_band.first_center for point in points])
    np.testing.assert_allclose(laterals, np.broadcast_to(laterals[0], np.shape(laterals)), atol=1e-6)
    assert np.ptp(laterals[0]) > 0.5, "the exit lane's centre swings across the corner's reference line"
    env.close()


def test_a_car_on_a_corner_is_framed_on_the_route_where_the_closest_lane_leaves_it():
    """On the corners the closest lane is partly the ring's lane on past the exit (or before the entry), off the
    route; a frame built from it went round the ring and left the route there, and every plan was infeasible until
    the car was on the exit's lanes (roundabout-v0, traced at seed 0). A car anywhere on a corner's lanes is framed
    on the route."""
    from types import SimpleNamespace

    from driveopt.sim.lane_graph import route_roads

    env = driveopt.gym_make("roundabout-v0", config={"action": {"type": "ContinuousAction"}})
    env.reset(seed=0)
    controller = driveopt.Controller("idm")
    controller.reset(env, seed=0)
    route = controller.task.route
    network = env.unwrapped.road.network
    frame, _ = ego_frame(env.unwrapped, route)

    def outer_lane(frame):  # [m] the frame's lateral of the ring's outer lane, which the entry and exit continue
        ring = next(b for p in frame.pieces for b in p.bands if b.road == ("se", "ex"))
        return ring.first_center + (ring.num_lanes - 1) * ring.lane_width

    off_route = 0
    for piece in (p for p in frame.pieces if isinstance(p.lane, CornerLane)):
        for s in np.arange(piece.s_start + piece.lo, piece.s_start + piece.hi, 0.5):
            x, y, heading, _, _ = frame.to_world(np.array([s]), np.array([outer_lane(frame)]))
            position = np.array([x[0], y[0]])
            closest = network.get_closest_lane_index(position, float(heading[0]))
            off_route += tuple(closest[:2]) not in route_roads(route)
            car = SimpleNamespace(lane_index=closest, position=position, heading=float(heading[0]), speed=8.0,
                                  LENGTH=5.0, WIDTH=2.0, action={"acceleration": 0.0, "steering": 0.0}, route=None)
            framed, me = ego_frame(SimpleNamespace(unwrapped=SimpleNamespace(
                vehicle=car, road=SimpleNamespace(network=network))), route)
            assert framed.ego_road in route_roads(route), (s, closest, framed.ego_road)
            assert abs(me.y - outer_lane(framed)) < 0.5, (s, me.y)
    assert off_route > 0, "some points of the corners lie closest to a lane off the route"
    env.close()


def test_its_longitudinal_runs_with_the_arc_length_whatever_its_arms():
    a, b, _ = _corner()
    for arms in ((1.0 / 3.0, 1.0 / 3.0), (0.25, 0.5), (0.5, 0.2)):
        corner = CornerLane(a, 28.0, 0.0, b, -12.0, -2.0, 20.0, arms)
        for lateral in (-2.0, 0.0, 2.0):  # the ends are each lane's map
            np.testing.assert_allclose(corner.position(0.0, lateral), a.position(28.0, lateral), atol=1e-9)
            np.testing.assert_allclose(corner.position(20.0, lateral), b.position(8.0, lateral - 2.0), atol=1e-9)
        points = np.array([corner.position(x, 0.0) for x in np.linspace(0.0, 20.0, 201)])
        steps = np.hypot(*np.diff(points, axis=0).T)
        assert np.ptp(steps) < 1e-3 * steps.mean(), arms


@pytest.mark.parametrize("env_id, sharpest", [("roundabout-v0", 0.09), ("roundabout-generic-v0", 0.065)])
def test_a_roundabouts_corners_turn_gently_and_keep_a_car_near_their_line_on_the_road(env_id, sharpest):
    """The corners' curvature, which bounds the planner's speed there (the centripetal bound: 9.2 m/s at 0.083 1/m and
    7 m/s^2), is at most ``sharpest`` [1/m] (0.129 and 0.091 with the ring's reach of 4 m and arms of a third), and a
    car within 0.9 m of a corner's reference line is on the road as upstream counts it: inside its closest lane."""
    env = driveopt.gym_make(env_id, config={"action": {"type": "ContinuousAction"}})
    env.reset(seed=0)
    controller = driveopt.Controller("idm")
    controller.reset(env, seed=0)
    network = env.unwrapped.road.network
    frame, _ = ego_frame(env.unwrapped, controller.task.route)
    corners = [p for p in frame.pieces if isinstance(p.lane, CornerLane)]
    assert len(corners) == 2
    for piece in corners:
        for longitudinal in np.linspace(0.0, piece.lane.length, 41):
            assert abs(lane_curvature(piece.lane, float(longitudinal))) < sharpest
            heading = piece.lane.heading_at(float(longitudinal))
            for lateral in (-0.9, 0.0, 0.9):
                position = piece.lane.position(float(longitudinal), lateral)
                lane = network.get_lane(network.get_closest_lane_index(position, heading))
                assert lane.on_lane(position), (longitudinal, lateral)
    env.close()
