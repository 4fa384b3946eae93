"""A route's lanes at a split as a goal (driveopt.sim.route_goal): found from the lane graph, widening with the
distance, given up when out of reach, and absent without a route."""

from __future__ import annotations

import pytest

import driveopt
from driveopt.sim.perception import Task, perceive
from driveopt.sim.road_frame import ego_frame
from driveopt.scene import Neighbour
from driveopt.sim.route_goal import RouteChange, Split, entry_flows, find_split, missed, split_goal

CONTINUOUS = {"action": {"type": "ContinuousAction"}}
EXIT = ["0", "1", "2", "exit"]


@pytest.fixture(scope="module")
def exit_env():
    env = driveopt.gym_make("exit-v0", config=CONTINUOUS)
    env.reset(seed=0)
    return env


def test_exit_routes_split_is_the_exit_lane_at_the_end_of_road_1_2(exit_env):
    frame, me = ego_frame(exit_env, EXIT)
    split = find_split(exit_env.unwrapped.road.network, frame, me.x)
    assert split == Split(("1", "2"), ("2", "exit"), 500.0, ((22.0, 26.0),), 4.0)
    straight, _ = ego_frame(exit_env, ["0", "1", "2", "3"])
    split = find_split(exit_env.unwrapped.road.network, straight, me.x)
    assert split.following == ("2", "3") and split.bands == ((-2.0, 22.0),)  # every lane but the exit lane


def test_the_goal_exists_only_with_a_route_and_narrows_the_far_lanes_first(exit_env):
    assert perceive(exit_env, Task(v_des=25.0)).goal is None  # no route: the scene and problem as before
    perception = perceive(exit_env, Task(v_des=25.0, route=EXIT))
    goal = perception.goal
    assert goal.bands == ((22.0, 26.0),) and goal.x[1] == 500.0
    ego, split = perception.scene.ego, find_split(exit_env.unwrapped.road.network, perception.frame, perception.scene.ego.x)
    flows = entry_flows(split, ego.x, ego.y, perception.scene.neighbours)
    assert any(flow is not None for flow in flows)  # the lanes to enter carry traffic, and the window slows to it
    assert goal.speed == split_goal(split, ego.x, ego.y, perception.kinematics.speed, RouteChange(), flows).speed
    assert goal.speed[1] < split_goal(split, ego.x, ego.y, perception.kinematics.speed).speed[1]
    split = Split(("1", "2"), ("2", "exit"), 500.0, ((22.0, 26.0),), 4.0)
    goal = split_goal(split, 175.0, 0.0, 25.0)  # at the latest one lane per 37.5 m, the band itself from 475 m
    assert goal.x == (475.0, 500.0) and goal.widen == pytest.approx(4.0 / 37.5)
    assert goal.speed == pytest.approx((0.0, 300.0 / (6 * 1.5)))  # 6 lanes to change in 300 m, 1.5 s each
    assert split_goal(split, 175.0, 24.0, 25.0).speed is None  # in the lane: no speed advice
    near = split_goal(split, 460.0, 16.0, 25.0)  # 2 lanes to change in the 15 m left before the band: not below 8 m/s
    assert near.speed == pytest.approx((0.0, RouteChange().min_speed)) and RouteChange().min_speed == 8.0


def test_entry_flows_are_the_mean_speeds_of_the_lanes_still_to_enter_in_the_order_they_are_entered():
    split = Split(("1", "2"), ("2", "exit"), 500.0, ((22.0, 26.0),), 4.0)  # the exit lane's centre at 24 m
    cars = [Neighbour(x=300.0, y=16.0, vx=10.0), Neighbour(x=350.0, y=16.3, vx=12.0),  # lane 4: 11 m/s
            Neighbour(x=310.0, y=20.0, vx=6.0),  # lane 5
            Neighbour(x=290.0, y=20.0, vx=30.0),  # lane 5, behind the ego by more than its length: not counted
            Neighbour(x=510.0, y=16.0, vx=30.0),  # past the split: not counted
            Neighbour(x=320.0, y=8.0, vx=2.0)]  # lane 2, the ego's own side of it: not a lane to enter
    assert entry_flows(split, 300.0, 12.0, cars) == pytest.approx((11.0, 6.0, None))  # lanes 4, 5, then the exit lane
    assert entry_flows(split, 300.0, 24.0, cars) == ()  # in the band
    back = Split(("1", "2"), ("2", "3"), 500.0, ((-2.0, 6.0),), 4.0)  # lanes 0-1, entered from lane 4 downwards
    assert entry_flows(back, 300.0, 16.0, cars) == pytest.approx((None, 2.0, None))  # lanes 3, 2, then 1


def test_the_speed_window_slows_to_the_traffic_of_each_lane_by_where_entering_it_must_begin():
    split = Split(("1", "2"), ("2", "exit"), 500.0, ((22.0, 26.0),), 4.0)
    pace = RouteChange()
    start = 500.0 - 25.0  # settle_distance at 25 m/s
    plain = split_goal(split, 300.0, 12.0, 25.0, pace)  # 3 lanes to change in 175 m at 1.5 s each: 39 m/s
    assert plain.speed == pytest.approx((0.0, 175.0 / 4.5))
    assert split_goal(split, 300.0, 12.0, 25.0, pace, (None, None, None)) == plain  # no traffic: as without
    # lanes at 11 and 6 m/s, the exit lane empty (its change timed at the ego's 25 m/s): the exit lane is entered from
    # start - 1.5 * 25, lane 5 from 1.5 * 6 before that, lane 4 from 1.5 * 11 before that
    lane5 = start - 1.5 * 25.0 - 1.5 * 6.0
    lane4 = lane5 - 1.5 * 11.0
    expected = min((11.0 ** 2 + 2 * 1.5 * (lane4 - 300.0)) ** 0.5, (6.0 ** 2 + 2 * 1.5 * (lane5 - 300.0)) ** 0.5)
    goal = split_goal(split, 300.0, 12.0, 25.0, pace, (11.0, 6.0, None))
    assert goal.speed == pytest.approx((0.0, expected)) and expected < 21.0
    assert goal.bands == plain.bands and goal.x == plain.x and goal.widen == plain.widen
    # past where lane 5 must be entered: its speed, not below min_speed (8 m/s; without traffic 45 m / 4.5 s); a fast
    # lane never raises the window
    assert split_goal(split, 430.0, 12.0, 25.0, pace).speed == pytest.approx((0.0, 10.0))
    assert split_goal(split, 430.0, 12.0, 25.0, pace, (11.0, 6.0, None)).speed == pytest.approx((0.0, 8.0))
    assert split_goal(split, 300.0, 12.0, 25.0, pace, (80.0, 80.0, 80.0)).speed == plain.speed


def test_a_split_out_of_reach_is_missed_and_one_within_reach_is_not():
    split = Split(("1", "2"), ("2", "exit"), 500.0, ((22.0, 26.0),), 4.0)
    assert not missed(split, 300.0, 0.0, 25.0)  # 200 m for 22 m across
    assert missed(split, 480.0, 0.0, 25.0)  # 20 m left for 22 m across
    assert not missed(split, 495.0, 24.0, 25.0)  # in the lane
    with pytest.raises(ValueError, match="lane_time"):
        RouteChange(lane_time=0.0)
    assert RouteChange(time_gap=0.0).time_gap == 0.0  # no gap while lanes remain
    for bad in (-0.1, 11.0, True):
        with pytest.raises(ValueError, match=r"time_gap must be a number in \[0, 10\]"):
            RouteChange(time_gap=bad)


def test_a_missed_split_reads_the_road_straight_on(exit_env):
    sim = exit_env.unwrapped
    saved = sim.vehicle.position.copy()
    try:
        sim.vehicle.position[:] = [490.0, 0.0]
        sim.vehicle.lane_index = sim.road.network.get_closest_lane_index(sim.vehicle.position, sim.vehicle.heading)
        perception = perceive(exit_env, Task(v_des=25.0, route=EXIT))
        assert perception.goal is None and ("2", "3") in perception.frame.roads
        assert perception.scene.road.num_lanes >= 6, "straight on: the lanes that continue past the split"
    finally:
        sim.vehicle.position[:] = saved
        sim.vehicle.lane_index = sim.road.network.get_closest_lane_index(sim.vehicle.position, sim.vehicle.heading)


@pytest.mark.parametrize("x", [501.6, 505.0])
@pytest.mark.parametrize("y", [4.0, 12.0, 20.0])
def test_a_car_just_past_a_split_it_did_not_take_is_framed_on_the_road_it_is_on(exit_env, x, y):
    """A few metres past the end of road ("1", "2"), in lane 1, 3 or 5 of ("2", "3"): the route's road ("1", "2") is
    within reach of its end, but its frame leads on into the exit lane only, 4-20 m away; the frame is the road the car
    is on, whose lanes hold it (in lanes 3 and 5 the route's frame held the car too, and its road, the exit lane alone,
    made every plan infeasible: the stop swerved towards the exit lane across the lanes between)."""
    sim = exit_env.unwrapped
    saved = sim.vehicle.position.copy()
    try:
        sim.vehicle.position[:] = [x, y]
        sim.vehicle.lane_index = sim.road.network.get_closest_lane_index(sim.vehicle.position, sim.vehicle.heading)
        if y == 4.0:  # 20 m beside the exit lane: not even the route's road holds it
            frame, me = ego_frame(exit_env, EXIT)
            assert ("2", "3") in frame.roads and ("2", "exit") not in frame.roads
            assert me.x == pytest.approx(x) and me.y == pytest.approx(4.0)
        perception = perceive(exit_env, Task(v_des=25.0, route=EXIT))
        assert perception.goal is None and perception.scene.road.num_lanes >= 6
        assert ("2", "exit") not in perception.frame.roads
        low, high = perception.scene.lateral_bounds
        assert low < perception.scene.ego.y < high
    finally:
        sim.vehicle.position[:] = saved
        sim.vehicle.lane_index = sim.road.network.get_closest_lane_index(sim.vehicle.position, sim.vehicle.heading)


ROUNDABOUT_EXIT = ["ser", "ses", "se", "ex", "ee", "nx", "nxs"]


def _place(env, position, heading):
    sim = env.unwrapped
    sim.vehicle.position[:] = position
    sim.vehicle.heading = heading
    sim.vehicle.lane_index = sim.road.network.get_closest_lane_index(sim.vehicle.position, sim.vehicle.heading)


def test_a_roundabouts_exit_leaves_by_the_outer_ring_lane_and_the_frame_covers_the_gap_to_it():
    """roundabout-v0's exit lane starts 5.6 m from the end of the outer ring lane, 2 m outside it and 5 m further round:
    no lane joins it, so the lane nearest its start (the outer one) is the one to be in; the frame's corner piece turns
    from the ring into the exit (no stretch of road between them the frame does not cover) and a car in that stretch is
    framed on the route, not on the ring going round again."""
    env = driveopt.gym_make("roundabout-v0", config=CONTINUOUS)
    env.reset(seed=0)
    _place(env, [15.0, -18.2], -2.4)  # on road ("ee", "nx"), before the exit
    frame, me = ego_frame(env, ROUNDABOUT_EXIT)
    split = find_split(env.unwrapped.road.network, frame, me.x)
    assert (split.road, split.following) == (("ee", "nx"), ("nx", "nxs"))
    band = next(b for p in frame.pieces for b in p.bands if b.road == ("ee", "nx"))
    assert split.bands == ((band.first_center + 0.5 * band.lane_width, band.high),)  # the outer lane only
    exit_band = next(b for p in frame.pieces for b in p.bands if b.road == ("nx", "nxs"))
    assert split.s == pytest.approx(exit_band.s_from, abs=1e-6)  # the split is where the exit's lane takes over
    exit_start = frame.locate(env.unwrapped.road.network.graph["nx"]["nxs"][0].position(0.0, 0.0))
    assert exit_start is not None and abs(exit_start[0] - split.s) < 2.0  # framed on the route, in the corner piece
    assert abs(exit_start[1] - exit_band.first_center) < 0.2  # on the exit's lane, which continues the outer ring lane
    _place(env, [7.3, -24.6], -2.9)  # past the ring lane's end, 1.9 m short of the exit lane's start
    assert env.unwrapped.vehicle.lane_index[:2] == ("nx", "ne")  # upstream's closest lane goes round the ring
    frame, me = ego_frame(env, ROUNDABOUT_EXIT)
    assert frame.ego_road == ("nx", "nxs") and frame.ego_band(me.x).road in {("ee", "nx"), ("nx", "nxs")}


def test_the_speed_before_a_curve_leaves_one_policy_period_to_the_next_decision():
    """A curve of radius 25 m 40 m ahead (4 m/s^2 lateral: 10 m/s there) enters the centripetal bound 15 m before it;
    braking at 1.5 m/s^2 over the 25 m before that allows 13.2 m/s now, but a decision once a second at 20 m/s covers
    20 of those metres first: 10.7 m/s. Bounded node by node, the plan can brake within the preview: the curve's
    speed is due at the curve, less one 2.5 m cell (14.6 and 12.2 m/s)."""
    from types import SimpleNamespace

    from driveopt.sim.perception import RoadPreview, curve_speed

    frame = SimpleNamespace(curves_ahead=lambda s_from, s_to: [(40.0, 1.0 / 25.0, 0.0)], curve_at=lambda s: (0.0, 0.0))
    preview = RoadPreview(lateral_acceleration=4.0)
    assert curve_speed(frame, 0.0, 0.0, 20.0, preview) == pytest.approx((100.0 + 2 * 1.5 * 25.0) ** 0.5)
    assert curve_speed(frame, 0.0, 0.0, 20.0, preview, period=1.0) == pytest.approx((100.0 + 2 * 1.5 * 5.0) ** 0.5)
    per_node = RoadPreview(lateral_acceleration=4.0, curvature_per_node=True)
    assert curve_speed(frame, 0.0, 0.0, 20.0, per_node) == pytest.approx((100.0 + 2 * 1.5 * 37.5) ** 0.5)
    assert curve_speed(frame, 0.0, 0.0, 20.0, per_node, period=1.0) == pytest.approx((100.0 + 2 * 1.5 * 17.5) ** 0.5)
    assert curve_speed(frame, 0.0, 0.0, 8.0, preview, period=1.0) == 8.0  # slower than the curve allows: unchanged


def test_on_a_curve_the_planned_rate_gives_the_car_beside_the_reference_line_its_bounds_own_speed():
    """The planner's speeds are rates along the reference line (here at d = 120 m, as a frame built on a road away
    from the world's x axis has it); a car 5 m outside a left curve of radius 25 m drives a 30 m circle at 1.2 times
    the rate, 5 m inside a 20 m one at 0.8 times it. The rate curve_speed plans gives the car itself 4 m/s^2 of
    lateral acceleration (sqrt(4 x 30) and sqrt(4 x 20) m/s), or the desired speed where that is lower; on the
    straight before the curve the rate is the desired speed."""
    from types import SimpleNamespace

    from driveopt.sim.perception import RoadPreview, curve_speed

    line = 120.0
    on_curve = SimpleNamespace(curves_ahead=lambda s_from, s_to: [(0.0, 1.0 / 25.0, line)], curve_at=lambda s: (1.0 / 25.0, line))
    preview = RoadPreview(lateral_acceleration=4.0)
    for d, scale in ((-5.0, 1.2), (5.0, 0.8)):
        car_speed = scale * curve_speed(on_curve, 0.0, line + d, 20.0, preview)
        assert car_speed == pytest.approx((4.0 * 25.0 * scale) ** 0.5)
        assert scale * curve_speed(on_curve, 0.0, line + d, 8.0, preview) == pytest.approx(8.0)
    before = SimpleNamespace(curves_ahead=lambda s_from, s_to: [], curve_at=lambda s: (0.0, line))
    assert curve_speed(before, 0.0, line - 5.0, 8.0, preview) == 8.0
