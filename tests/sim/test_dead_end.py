"""A road that ends with nothing after it: the frame knows where, and the scene stands a wall across its lanes there."""

from __future__ import annotations

import math

import jax
import numpy as np
import pytest
from highway_env.road.lane import CircularLane, StraightLane
from highway_env.road.road import RoadNetwork

from driveopt import EgoState, Road, Scene, build_problem, plan
from driveopt.sim.perception import DEAD_END_WALL, RoadPreview, dead_end_walls
from driveopt.sim.road_frame import build_frame


def _bend(width: float = 4.0) -> RoadNetwork:
    """Two lanes: 50 m straight along +x, a quarter circle (radius 30 m, lane 0) to the left, 50 m straight along +y;
    nothing after node "d"."""
    net = RoadNetwork()
    for i in range(2):
        net.add_lane("a", "b", StraightLane([0.0, i * width], [50.0, i * width], width=width))
        net.add_lane("b", "c", CircularLane([50.0, 30.0], 30.0 - i * width, -math.pi / 2, 0.0, clockwise=True,
                                            width=width))
        net.add_lane("c", "d", StraightLane([80.0 - i * width, 30.0], [80.0 - i * width, 80.0], width=width))
    return net


def test_the_frame_ends_where_the_last_road_ends_and_a_wall_stands_across_its_lanes_within_reach():
    frame = build_frame(_bend(), ("a", "b"))
    end = frame.dead_end
    assert end.road == ("c", "d")
    assert end.s_to == pytest.approx(50.0 + 0.5 * math.pi * 30.0 + 50.0)
    s_end, d_end, *_ = frame.locate(np.array([80.0, 80.0]))  # the end of lane 0, in the frame
    assert s_end == pytest.approx(end.s_to) and d_end == pytest.approx(0.0, abs=1e-9)
    walls = dead_end_walls(frame, end.s_to - 20.0, 10.0, RoadPreview(), ("c", "d"))
    assert [(w.x, w.y, w.vx, w.vy) for w in walls] == [(end.s_to + 0.5 * DEAD_END_WALL, 0.0, 0.0, 0.0),
                                                      (end.s_to + 0.5 * DEAD_END_WALL, 4.0, 0.0, 0.0)]
    assert all(w.width == 4.0 and w.yaw == 0.0 for w in walls)
    assert len(dead_end_walls(frame, end.s_to - 20.0, 10.0, RoadPreview(), ("b", "c"))) == 2  # past the destination
    # beyond the reach (max(30 m, 8 s at the speed)): none; nor once the car is past the end
    assert dead_end_walls(frame, end.s_to - 60.0, 5.0, RoadPreview(), ("c", "d")) == []
    assert len(dead_end_walls(frame, end.s_to - 60.0, 10.0, RoadPreview(), ("c", "d"))) == 2
    assert dead_end_walls(frame, end.s_to + 2.0, 0.0, RoadPreview(), ("c", "d")) == []


def test_without_a_destination_or_before_it_a_dead_end_stands_no_wall():
    """The road is taken to go on as the env has it (upstream's merge-v0 ends its episode before its road ends)."""
    frame = build_frame(_bend(), ("a", "b"))
    assert frame.dead_end is not None
    assert dead_end_walls(frame, frame.dead_end.s_to - 20.0, 10.0, RoadPreview(), None) == []
    assert dead_end_walls(frame, frame.dead_end.s_to - 20.0, 10.0, RoadPreview(), ("x", "y")) == []  # not on the frame


def test_measured_along_the_egos_lane_the_dead_end_moves_with_the_arc():
    frame = build_frame(_bend(), ("a", "b")).along(4.0)  # the left lane's arc has a radius of 26 m
    assert frame.dead_end.s_to == pytest.approx(50.0 + 0.5 * math.pi * 26.0 + 50.0)
    s_end, *_ = frame.locate(np.array([76.0, 80.0]))
    assert s_end == pytest.approx(frame.dead_end.s_to)


def test_a_loop_has_no_dead_end_and_a_far_one_stands_no_wall():
    loop = RoadNetwork()
    loop.add_lane("a", "b", CircularLane([0.0, 0.0], 30.0, 0.0, math.pi, clockwise=True))
    loop.add_lane("b", "a", CircularLane([0.0, 0.0], 30.0, math.pi, 2 * math.pi, clockwise=True))
    assert build_frame(loop, ("a", "b")).dead_end is None
    long = RoadNetwork()  # driveopt's own scenarios' roads: 10 km
    long.add_lane("a", "b", StraightLane([0.0, 0.0], [10000.0, 0.0]))
    frame = build_frame(long, ("a", "b"), ego_longitudinal=9000.0)
    assert frame.dead_end.s_to == 10000.0
    assert dead_end_walls(frame, 9000.0, 30.0, RoadPreview(), ("a", "b")) == []  # 1 km: beyond 8 s at 30 m/s


def test_the_plan_stops_before_the_wall_at_a_dead_end(small_config):
    """At 10 m/s, 25 m before the end of a one-lane road: the chosen plan, feasible, ends standing with the car's
    front before the road's end; without the wall it drives on past it."""
    frame = build_frame(_bend(), ("a", "b"))
    end = frame.dead_end.s_to
    ego = EgoState(x=end - 25.0, y=0.0, vx=10.0)
    road = Road(num_lanes=1, lane_width=4.0)
    walled = Scene(ego=ego, road=road, neighbours=tuple(dead_end_walls(frame, ego.x, 10.0, RoadPreview(), ("c", "d")))[:1],
                   v_des=10.0)
    for scene, stops in ((walled, True), (Scene(ego=ego, road=road, v_des=10.0), False)):
        result = plan(build_problem(scene, small_config.basis), small_config, key=jax.random.PRNGKey(0),
                      x_offset=ego.x)
        traj = result.safe_trajectory
        front = np.asarray(traj.x) + 0.5 * ego.length
        assert (front.max() <= end) == stops
        if stops:
            assert result.status.name == "SUCCESS" and float(np.asarray(traj.speed)[-1]) < 0.5
