"""The Frenet frame along a route through highway-env's lane graph: straight roads exactly, arcs, plans back to world."""

from __future__ import annotations

import math

import numpy as np
import pytest
from highway_env.road.lane import CircularLane, StraightLane
from highway_env.road.road import RoadNetwork

from driveopt.scene import CURVATURE_CELL, CURVATURE_CELLS
from driveopt.sim.road_frame import RoadFrameError, build_frame, lane_curvature
from driveopt.sim.world_plan import to_world
from driveopt.trajectory import Trajectory


def _loop(radius: float = 30.0, width: float = 4.0, y0: float = 0.0) -> RoadNetwork:
    """A two-lane road: 50 m straight along +x at y = y0, then a left-turning quarter circle, then 50 m straight
    along +y."""
    net = RoadNetwork()
    for i in range(2):
        net.add_lane("a", "b", StraightLane([0.0, y0 + i * width], [50.0, y0 + i * width], width=width))
        net.add_lane("b", "c", CircularLane([50.0, y0 + radius], radius - i * width, -math.pi / 2, 0.0, clockwise=True,
                                            width=width))
        net.add_lane("c", "d", StraightLane([50.0 + radius - i * width, y0 + radius],
                                            [50.0 + radius - i * width, y0 + radius + 50.0], width=width))
    return net


def test_a_straight_road_along_x_is_the_world_frame_exactly():
    net = RoadNetwork()
    for i in range(3):
        net.add_lane("a", "b", StraightLane([0.0, 4.0 * i], [300.0, 4.0 * i]))
        net.add_lane("b", "c", StraightLane([300.0, 4.0 * i], [500.0, 4.0 * i]))
    frame = build_frame(net, ("b", "c"))
    rng = np.random.default_rng(0)
    for x, y in rng.uniform([-50.0, -3.0], [600.0, 11.0], size=(50, 2)):
        s, d, *_ = frame.locate(np.array([x, y]))
        assert (s, d) == (300.0 + (x - 300.0), 0.0 + (y - 0.0)), "the ego road's lane measures every straight section"
    road = frame.road(350.0, 30.0, 10.0)
    assert (road.num_lanes, road.lane_width, road.first_lane_center, road.curvature) == (3, 4.0, 0.0, 0.0)
    assert not road.curvature_profile.any()


def test_an_arc_is_measured_along_its_reference_lane():
    net = _loop()
    frame = build_frame(net, ("a", "b"))
    assert frame.roads == (("a", "b"), ("b", "c"), ("c", "d"))
    quarter = 0.5 * math.pi * 30.0
    # the left lane's centre halfway round the arc: s along the reference (lowest-offset) lane, d = one lane width
    lane = net.get_lane(("b", "c", 1))
    s, d, piece, *_ = frame.locate(lane.position(0.5 * lane.length, 0.0))
    assert s == pytest.approx(50.0 + 0.5 * quarter, abs=1e-9) and d == pytest.approx(4.0, abs=1e-9)
    assert lane_curvature(piece.lane, 1.0) == pytest.approx(1.0 / 30.0)
    # the straight after the arc continues the arc length
    s, d, *_ = frame.locate(np.array([80.0, 40.0]))
    assert s == pytest.approx(50.0 + quarter + 10.0) and d == pytest.approx(0.0, abs=1e-9)
    road = frame.road(55.0, 30.0, 20.0)
    assert road.num_lanes == 2 and road.curvature == pytest.approx(1.0 / 30.0)
    assert frame.road(10.0, 10.0, 10.0).curvature == 0.0


def test_the_curvature_per_node_is_the_arcs_in_the_cells_it_spans_and_their_neighbours():
    """From s = 10 m the arc (1/30 1/m) spans 40 m to 40 + 47.1 m ahead: cells 16 to 34 of 2.5 m, widened by one
    cell each way; straight elsewhere; nothing in the cells beyond the curvature preview."""
    frame = build_frame(_loop(), ("a", "b"))
    cells = frame.road(10.0, 10.0, 200.0, behind=2.5, per_node=True).curvature_profile
    assert cells.shape == (CURVATURE_CELLS,)
    quarter = 0.5 * math.pi * 30.0
    first, last = int(40.0 // CURVATURE_CELL), int((40.0 + quarter) // CURVATURE_CELL)
    curved = np.zeros(CURVATURE_CELLS, bool)
    curved[first - 1:last + 2] = True
    assert np.allclose(cells[curved], 1.0 / 30.0) and not cells[~curved].any()
    # a preview of 45 m keeps the cells that start within it (the arc's first ones) and no others
    short = frame.road(10.0, 10.0, 45.0, behind=2.5, per_node=True).curvature_profile
    kept = CURVATURE_CELL * np.arange(CURVATURE_CELLS) <= 45.0
    assert np.array_equal(short[kept], cells[kept]) and short[kept].any() and not short[~kept].any()
    # without per_node the preview's sharpest curvature is every cell's
    assert np.array_equal(frame.road(10.0, 10.0, 45.0, behind=2.5).curvature_profile, np.full(CURVATURE_CELLS, 1.0 / 30.0))


def test_the_curvatures_line_is_where_the_frame_puts_the_reference_lane():
    """The loop 120 m up the world's y axis: the frame's d is 120 m on the reference lane, so the arc's curvature is
    that of the line d = 120 m (``Road.curvature_origin``), not of d = 0."""
    frame = build_frame(_loop(y0=120.0), ("a", "b"))
    road = frame.road(55.0, 30.0, 20.0)
    assert road.curvature == pytest.approx(1.0 / 30.0) and road.curvature_origin == pytest.approx(120.0)
    assert road.first_lane_center == pytest.approx(120.0)
    assert frame.curve_at(70.0) == (pytest.approx(1.0 / 30.0), pytest.approx(120.0))


def test_a_right_curves_cells_keep_its_sign():
    """The same quarter circle turning right (away from +d, where the second lane is the outer one): its cells hold
    -1/30 1/m, as the reference line's signed curvature does, so the car's offset is known to be on the outside."""
    net = RoadNetwork()
    for i in range(2):
        net.add_lane("a", "b", StraightLane([0.0, 4.0 * i], [50.0, 4.0 * i], width=4.0))
        net.add_lane("b", "c", CircularLane([50.0, -30.0], 30.0 + 4.0 * i, math.pi / 2, 0.0, clockwise=False, width=4.0))
    frame = build_frame(net, ("a", "b"))
    cells = frame.road(10.0, 10.0, 200.0, behind=2.5, per_node=True).curvature_profile
    assert cells.min() == pytest.approx(-1.0 / 30.0) and cells.max() == 0.0
    assert np.allclose(frame.road(10.0, 10.0, 45.0, behind=2.5).curvature_profile, -1.0 / 30.0)


def test_a_plan_along_the_arc_turns_back_into_the_lanes_world_motion():
    frame = build_frame(_loop(), ("a", "b"))
    t = np.linspace(0.0, 3.0, 31)
    speed, d = 10.0, 4.0  # [m/s] along the reference line, [m] on the second lane's centre (the inner circle)
    s = 55.0 + speed * t
    zeros = np.zeros_like(t)
    plan = Trajectory(t=t, x=s, y=np.full_like(t, d), vx=np.full_like(t, speed), vy=zeros, ax=zeros, ay=zeros,
                      speed=np.full_like(t, speed), heading=zeros, curvature=zeros, acceleration=zeros)
    world = to_world(plan, frame)
    lane = _loop().get_lane(("b", "c", 1))
    for k in range(len(t)):
        longitudinal, lateral = lane.local_coordinates(np.array([world.x[k], world.y[k]]))
        assert lateral == pytest.approx(0.0, abs=1e-9), "the plan stays on the second lane's centre line"
        course = math.atan2(world.vy[k], world.vx[k])
        assert math.cos(course - lane.heading_at(longitudinal)) == pytest.approx(1.0, abs=1e-12)
        # on a 26 m radius the car covers 26/30 of the reference line's arc length, and turns at v / 26 m
        assert math.hypot(world.vx[k], world.vy[k]) == pytest.approx(speed * 26.0 / 30.0)
        acceleration = math.hypot(world.ax[k], world.ay[k])
        assert acceleration == pytest.approx((speed * 26.0 / 30.0) ** 2 / 26.0)


def test_measured_along_the_ego_lane_an_arc_keeps_every_points_d_and_a_lane_keeping_plan_its_speed():
    """The loop's frame measured along the second lane (d = 4 m): the arc is the 26 m circle's, so the straight after
    it starts 26/30 of a quarter circle after the arc's start, every world point keeps its d, the arc's curvature is
    1/26 1/m of the line d = 4 m, and a plan along that lane at a constant 10 m/s rate moves at 10 m/s in the world
    on the straight, the arc and the straight after it (measured along the lowest lane the same plan would drop to
    26/30 of that on the arc)."""
    frame = build_frame(_loop(), ("a", "b"))
    along = frame.along(4.0)
    quarter = 0.5 * math.pi * 30.0
    assert along.ego_s == frame.ego_s  # on the first straight
    rng = np.random.default_rng(1)
    for x, y in rng.uniform([0.0, -1.0], [79.0, 79.0], size=(40, 2)):
        before, after = frame.locate(np.array([x, y])), along.locate(np.array([x, y]))
        assert (before is None) == (after is None)
        if before is not None:
            assert after[1] == pytest.approx(before[1], abs=1e-9)
    end = frame.locate(np.array([80.0, 70.0]))  # on the straight after the arc, 20 m along it
    assert along.locate(np.array([80.0, 70.0]))[0] == pytest.approx(end[0] - quarter * 4.0 / 30.0, abs=1e-9)
    assert along.curve_at(50.0 + 0.5 * quarter * 26.0 / 30.0) == (pytest.approx(1.0 / 26.0), pytest.approx(4.0))
    t = np.linspace(0.0, 8.0, 81)
    zeros = np.zeros_like(t)
    s = 30.0 + 10.0 * t
    plan = Trajectory(t=t, x=s, y=np.full_like(t, 4.0), vx=np.full_like(t, 10.0), vy=zeros, ax=zeros, ay=zeros,
                      speed=np.full_like(t, 10.0), heading=zeros, curvature=zeros, acceleration=zeros)
    world = to_world(plan, along)
    assert np.allclose(np.hypot(world.vx, world.vy), 10.0)


def test_where_a_roads_lanes_leave_a_gap_between_them_the_planner_keeps_the_egos_lane():
    """Two 4 m lanes 4.1 m apart from 100 m on (upstream's racetrack-v0 has 8.7 cm between its ("f", "g") lanes,
    a strip on no lane, which upstream counts as off the road): within the lane preview (or the gap preview) of it and
    along it the road is the ego's lane alone; before, and where the lanes are adjacent, both lanes."""
    net = RoadNetwork()
    for i, spacing in enumerate((4.0, 4.1)):
        for lane in range(2):
            start = 100.0 * i
            net.add_lane(f"n{i}", f"n{i + 1}", StraightLane([start, spacing * lane], [start + 100.0, spacing * lane],
                                                           width=4.0))
    frame = build_frame(net, ("n0", "n1"))
    assert frame.road(20.0, 30.0, 10.0, d=4.0).num_lanes == 2  # the gap is beyond the preview
    near = frame.road(80.0, 30.0, 10.0, d=3.6)
    assert (near.num_lanes, near.first_lane_center) == (1, 4.0)
    assert frame.road(80.0, 30.0, 10.0, d=0.3).first_lane_center == 0.0
    assert frame.road(80.0, 30.0, 10.0).num_lanes == 2  # without the ego's offset: the lanes as they are
    # a shorter gap preview: both lanes until the gapped road starts within it, then the ego's lane to its end
    assert frame.road(80.0, 30.0, 10.0, d=3.6, gap_preview=15.0).num_lanes == 2
    assert frame.road(88.0, 30.0, 10.0, d=3.6, gap_preview=15.0).num_lanes == 1
    assert frame.road(150.0, 30.0, 10.0, d=3.6, gap_preview=15.0).num_lanes == 1


def test_lanes_that_are_not_parallel_are_named():
    net = RoadNetwork()
    net.add_lane("a", "b", StraightLane([0.0, 0.0], [100.0, 0.0]))
    net.add_lane("a", "b", StraightLane([0.0, 4.0], [100.0, 9.0]))
    with pytest.raises(RoadFrameError, match=r"lane \('a', 'b', 1\) is not parallel to lane \('a', 'b', 0\)"):
        build_frame(net, ("a", "b"))


def test_a_crossing_road_leaves_the_frame_along_the_route():
    """Crossing lanes are represented (their traffic is predicted along them, driveopt.sim.crossing): the frame is the
    route's, and a point of the crossing lane off the route's lanes is not on them."""
    net = RoadNetwork()
    net.add_lane("a", "b", StraightLane([0.0, 0.0], [100.0, 0.0]))
    net.add_lane("x", "y", StraightLane([50.0, -30.0], [50.0, 30.0]))
    frame = build_frame(net, ("a", "b"))
    assert frame.roads == (("a", "b"),)
    s, d, *_ = frame.locate(np.array([50.0, 10.0]))
    assert (s, d) == pytest.approx((50.0, 10.0))


def test_the_frame_starts_on_the_routes_branch_where_a_junctions_branches_overlap():
    """At a junction whose branches start together the simulator's closest lane can be another branch than the
    route's: the frame starts from the route's branch the car is on."""
    from types import SimpleNamespace

    from driveopt.sim.road_frame import ego_frame

    net = RoadNetwork()
    net.add_lane("a", "b", StraightLane([0.0, 0.0], [100.0, 0.0], width=4.0))
    net.add_lane("b", "c", StraightLane([100.0, 0.0], [130.0, 0.0], width=4.0))  # straight on
    net.add_lane("b", "d", StraightLane([100.0, 0.0], [125.0, -15.0], width=4.0))  # the route's branch, 31 deg off
    car = SimpleNamespace(lane_index=("b", "c", 0), position=np.array([102.0, -1.1]), heading=-0.5, speed=5.0,
                          LENGTH=5.0, WIDTH=2.0, action={"acceleration": 0.0, "steering": 0.0}, route=None)
    env = SimpleNamespace(unwrapped=SimpleNamespace(vehicle=car, road=SimpleNamespace(network=net)))
    assert ego_frame(env, ["a", "b", "d"])[0].ego_road == ("b", "d")
    assert ego_frame(env, ["a", "b", "c"])[0].ego_road == ("b", "c"), "on the route's own road: kept"


def test_a_junction_at_the_end_of_the_route_is_named():
    net = RoadNetwork()
    net.add_lane("a", "b", StraightLane([0.0, 0.0], [100.0, 0.0]))
    net.add_lane("b", "c", StraightLane([100.0, 0.0], [100.0, 80.0]))  # a right angle: not a road the frame follows
    with pytest.raises(RoadFrameError, match=r"road \('a', 'b'\) ends at node 'b'.*turning 90 deg onto road \('b', 'c'\)"):
        build_frame(net, ("a", "b"))


def test_an_oncoming_road_is_not_a_junction():
    net = RoadNetwork()
    net.add_lane("a", "b", StraightLane([0.0, 0.0], [100.0, 0.0]))
    net.add_lane("b", "a", StraightLane([100.0, 0.0], [0.0, 0.0]))
    frame = build_frame(net, ("a", "b"))
    assert frame.roads == (("a", "b"),) and frame.road(10.0, 10.0, 10.0).num_lanes == 1
