"""The goal input (driveopt.goal): its checks, the bounds and desired speed it sets, and no goal = no change."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from driveopt.config import PlannerConfig
from driveopt.goal import Goal
from driveopt.planner import PlanStatus, plan
from driveopt.problem import build_problem
from driveopt.scene import EgoState, Neighbour, ProblemError, Road, Scene, load_scene

ROAD = Road(num_lanes=3, lane_width=4.0, first_lane_center=0.0)  # lanes centred at 0, 4, 8 m


def scene(x=0.0, y=0.0, vx=10.0, neighbours=()):
    return Scene(ego=EgoState(x=x, y=y, vx=vx), road=ROAD, neighbours=neighbours, v_des=15.0)


def test_no_goal_builds_the_same_problem():
    s = load_scene("slow-leader-three-lane")
    before, after = build_problem(s), build_problem(s, goal=None, time=3.0)
    for name in before._fields:
        np.testing.assert_array_equal(np.asarray(getattr(before, name)), np.asarray(getattr(after, name)), err_msg=name)


def test_an_empty_goal_leaves_bounds_and_speed():
    s = scene()
    problem, plain = build_problem(s, goal=Goal()), build_problem(s)
    assert float(problem.y_lb) == float(plain.y_lb) and float(problem.y_ub) == float(plain.y_ub)
    assert float(problem.v_des) == float(plain.v_des)


@pytest.mark.slow  # a compile of its own (about 20 s); the goal-free plans are every other test's
def test_no_goal_plans_bit_for_bit_as_before():
    s = load_scene("slow-leader-three-lane")
    config = PlannerConfig().with_samples(40)
    key = jax.random.PRNGKey(3)
    a = plan(build_problem(s), config, key=key)
    b = plan(build_problem(s, goal=None), config, key=key)
    np.testing.assert_array_equal(a.coeffs, b.coeffs)
    np.testing.assert_array_equal(a.trajectory.x, b.trajectory.x)


def test_lanes_become_bands_and_the_near_band_bounds_the_centre():
    goal = Goal.in_lanes(ROAD, [2], x=(50.0, 80.0))
    assert goal.bands == ((6.0, 10.0),)
    lo, hi = goal.lateral_bounds(scene(x=30.0))  # 20 m to the goal's start: near
    assert lo == pytest.approx(6.3) and hi == pytest.approx(8.7)  # the band within the road (upper 10 - 1 m), inset 0.3 m
    problem = build_problem(scene(x=30.0), goal=goal)
    assert float(problem.y_lb) == pytest.approx(6.3) and float(problem.y_ub) == pytest.approx(8.7)


def test_a_far_goal_leaves_the_road_bounds():
    goal = Goal.in_lanes(ROAD, [2], x=(500.0, 520.0))
    assert goal.lateral_bounds(scene(x=0.0)) == scene().lateral_bounds


def test_the_nearest_of_several_bands_is_chosen():
    goal = Goal.in_lanes(ROAD, [0, 2])
    assert goal.lateral_bounds(scene(y=7.0))[0] > 5.0
    assert goal.lateral_bounds(scene(y=1.0))[1] < 3.0


def test_a_slow_car_in_the_band_defers_it_until_passed():
    goal = Goal.in_lanes(ROAD, [0], x=(60.0, 70.0))
    slow = Neighbour(x=40.0, y=0.0, vx=0.1)
    assert goal.lateral_bounds(scene(x=20.0, y=4.0, neighbours=(slow,))) == scene().lateral_bounds
    assert goal.lateral_bounds(scene(x=50.0, y=4.0, neighbours=(slow,)))[1] < 2.0  # passed: the band is imposed


def test_speed_window_and_time_window_set_v_des():
    assert Goal(speed=(5.0, 8.0)).desired_speed(scene()) == 8.0
    # 100 m to the start, window closes in 5 s: an average of 20 m/s; from 10 m/s, the end speed of a steady
    # acceleration that averages it (10 -> 30 m/s); a car already at 20 m/s or faster holds the average
    assert Goal(x=(100.0, 120.0), time=(0.0, 5.0)).desired_speed(scene()) == pytest.approx(30.0)
    assert Goal(x=(100.0, 120.0), time=(0.0, 5.0)).desired_speed(scene(vx=20.0)) == pytest.approx(20.0)
    assert Goal(x=(100.0, 120.0), time=(0.0, 5.0)).desired_speed(scene(vx=25.0)) == pytest.approx(20.0)
    # the end 40 m away, the window opens in 10 s: at most 4 m/s
    assert Goal(x=(30.0, 40.0), time=(10.0, 20.0)).desired_speed(scene()) == pytest.approx(4.0)
    assert Goal(x=(30.0, 40.0), time=(10.0, 20.0)).desired_speed(scene(), time=8.0) == pytest.approx(15.0)


@pytest.mark.parametrize("fields, message", [
    ({"bands": [(2.0, 1.0)]}, "low <= high"),
    ({"x": (1.0,)}, "pair"),
    ({"speed": (-1.0, 2.0)}, ">= 0"),
    ({"time": (0.0, float("nan"))}, "finite"),
    ({"lead_time": -1.0}, "lead_time"),
    ({"bands": "lane"}, "sequence"),
])
def test_bad_goals_are_refused_in_one_line(fields, message):
    with pytest.raises(ProblemError, match=message) as info:
        Goal(**fields)
    assert "\n" not in str(info.value)


def test_lanes_out_of_the_road_are_refused():
    with pytest.raises(ProblemError, match="not lanes of the road"):
        Goal.in_lanes(ROAD, [3])
    with pytest.raises(ProblemError, match="must be a driveopt.goal.Goal"):
        build_problem(scene(), goal=(1, 2))


def test_a_widened_band_reaches_further_the_further_the_goal_and_keeps_the_lanes_inside():
    goal = Goal(bands=((6.0, 10.0),), x=(100.0, 110.0), widen=0.04, lead_distance=200.0)  # 4 m wider per side at 100 m
    lo, hi = goal.lateral_bounds(scene(x=0.0, y=4.0))
    assert lo == pytest.approx(2.3) and hi == pytest.approx(8.7)  # [2, 14] within the road, inset 0.3 m
    assert goal.lanes(scene(x=0.0, y=4.0), (lo, hi)) == (4.0, 4.0, 2)  # the ego's own lane and the band's
    assert goal.lanes(scene(x=0.0, y=8.0), (lo, hi)) == (8.0, 4.0, 1)  # in the band: its own lane
    assert goal.lateral_bounds(scene(x=100.0, y=8.0)) == pytest.approx((6.3, 8.7))  # at its start: the band itself
    assert Goal(bands=((6.0, 10.0),), x=(100.0, 110.0)).lateral_bounds(scene(x=99.0)) == pytest.approx((6.3, 8.7))
    with pytest.raises(ProblemError, match="widen"):
        Goal(widen=-1.0)


def test_a_widened_band_never_excludes_the_egos_lane_or_position():
    goal = Goal(bands=((6.0, 10.0),), x=(100.0, 110.0), widen=0.04, lead_distance=200.0)
    assert goal.lateral_bounds(scene(x=0.0, y=0.0)) == pytest.approx((0.0, 8.7))  # the band would start at 2.3 m
    assert goal.lateral_bounds(scene(x=100.0, y=0.0)) == pytest.approx((0.0, 8.7))  # ... or at 6.3 m
    assert goal.lateral_bounds(scene(x=100.0, y=4.6)) == pytest.approx((4.0, 8.7))  # its lane's centre, and itself
    assert goal.lateral_bounds(scene(x=100.0, y=3.4)) == pytest.approx((3.4, 8.7))
    # a goal that is not widened (a CommonRoad goal region) still requires its band
    assert Goal(bands=((6.0, 10.0),), x=(100.0, 110.0)).lateral_bounds(scene(x=100.0)) == pytest.approx((6.3, 8.7))


def test_a_car_alongside_in_the_next_lane_towards_a_widened_band_leaves_a_feasible_plan_that_keeps_clear(small_config):
    """The band's edge has passed the ego (the latest pace of the lane changes): requiring it would push the car into
    the one beside it (every plan infeasible, as exit-v0's route did at 5 Hz); the plan keeps its lane until it can
    change."""
    alongside = Neighbour(x=3.0, y=4.0, vx=22.0)
    s = Scene(ego=EgoState(x=0.0, y=0.0, vx=25.0), road=ROAD, neighbours=(alongside,), v_des=25.0)
    goal = Goal(bands=((6.0, 10.0),), x=(100.0, 110.0), widen=0.04, lead_distance=200.0, block_speed=9999.0)  # a route's
    problem = build_problem(s, goal=goal)
    assert float(problem.y_lb) == pytest.approx(0.0)
    result = plan(problem, small_config, key=jax.random.PRNGKey(0))
    assert result.status == PlanStatus.SUCCESS
    t, x, y = (np.asarray(a) for a in (result.trajectory.t, result.trajectory.x, result.trajectory.y))
    other_x = alongside.x + alongside.vx * t
    overlapping = (np.abs(x - other_x) < s.ego.length) & (np.abs(y - alongside.y) < s.ego.width)  # the two boxes
    assert not overlapping.any()
