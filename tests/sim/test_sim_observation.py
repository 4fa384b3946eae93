"""Scene building from highway-env and the 55-dim observation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import reset_env

from driveopt.observation import (
    DUMMY_DX,
    OBSERVATION_DIM,
    ObservationError,
    check_observation,
    is_dummy,
    neighbour_mask,
    observation_vector,
    split_observation,
)
from driveopt.prediction import PathNeighbour, ellipse_semi_axes
from driveopt.problem import build_problem
from driveopt.scene import EgoState, Neighbour, Road, Scene
from driveopt.sim.env import step_env
from driveopt.sim.perception import Task, perceive, scene_from_env
from driveopt.sim.road_frame import RoadFrameError, build_frame
from driveopt.sim.scenarios import get_scenario

# ----------------------------------------------------------------------------- synthetic scenes


def _scene(neighbours, ego=EgoState(x=100.0, y=4.0, vx=12.0, vy=0.5)):
    return Scene(ego=ego, road=Road(num_lanes=2), neighbours=tuple(neighbours))


def _ring(count, seed=0):
    """``count`` neighbours at distinct distances from the ego, in shuffled order."""
    rng = np.random.default_rng(seed)
    dist = rng.permutation(np.arange(1, count + 1) * 7.0)
    return [Neighbour(x=100.0 + d * (-1) ** i, y=float(rng.choice([0.0, 4.0])), vx=9.0 + i, vy=0.1 * i) for i, d in enumerate(dist)]


def test_layout_and_ego_features():
    scene = _scene(_ring(3))
    obs = observation_vector(scene)
    assert obs.shape == (OBSERVATION_DIM,) == (55,) and obs.dtype == np.float32
    y_lb, y_ub = scene.lateral_bounds  # ego centre bounds: edges -2, 6 m, half width 1 m
    assert (y_lb, y_ub) == (-1.0, 5.0)
    np.testing.assert_allclose(obs[:5], [5.0 - 4.0, -1.0 - 4.0, 12.0, 0.5, math.atan2(0.5, 12.0)], rtol=1e-6)


def test_padding_keeps_every_real_vehicle_nearest_first():
    neighbours = _ring(4)
    scene = _scene(neighbours)
    ego_part, rows = split_observation(observation_vector(scene))
    dummy = is_dummy(rows)
    np.testing.assert_array_equal(dummy, [False] * 4 + [True] * 6)
    dist = np.hypot(rows[:4, 0], rows[:4, 1])
    assert np.all(np.diff(dist) > 0), "nearest first"
    want = sorted((n.x - 100.0, n.y - 4.0, n.vx, n.vy) for n in neighbours)
    got = sorted(tuple(float(v) for v in r[:4]) for r in rows[:4])
    np.testing.assert_allclose(got, want, rtol=1e-6, err_msg="every real vehicle appears once, none overwritten")
    np.testing.assert_array_equal(rows[4:], np.tile([DUMMY_DX, 0, 0, 0, 0], (6, 1)))


@pytest.mark.parametrize("count", [10, 13])
def test_ten_nearest_are_kept_when_more_are_visible(count):
    neighbours = _ring(count, seed=count)
    ego = _scene(neighbours).ego
    _, rows = split_observation(observation_vector(_scene(neighbours)))
    assert not is_dummy(rows).any()
    nearest = sorted(neighbours, key=lambda n: math.hypot(n.x - ego.x, n.y - ego.y))[:10]
    np.testing.assert_allclose(rows[:, 0], [n.x - ego.x for n in nearest], rtol=1e-6)
    np.testing.assert_allclose(rows[:, 2], [n.vx for n in nearest], rtol=1e-6)
    np.testing.assert_allclose(rows[:, 4], [n.heading for n in nearest], rtol=1e-5, atol=1e-7)


def test_far_real_vehicle_is_not_mistaken_for_padding():
    scene = _scene([Neighbour(x=100.0 + 900.0, y=4.0, vx=0.0)])
    _, rows = split_observation(observation_vector(scene))
    assert rows[0, 0] == pytest.approx(900.0) and not is_dummy(rows)[0]


def test_no_neighbours_is_all_padding():
    _, rows = split_observation(observation_vector(_scene([])))
    assert is_dummy(rows).all()


def test_custom_neighbour_count():
    obs = observation_vector(_scene(_ring(3)), num_neighbours=4)
    assert obs.shape == (25,)


@pytest.mark.parametrize("bad", [np.zeros(54), np.zeros((2, 3, 55)), np.array(["a"] * 55)])
def test_wrong_shapes_are_rejected(bad):
    with pytest.raises(ObservationError):
        check_observation(bad)


def test_nan_is_rejected_with_its_index():
    obs = np.zeros((2, 55))
    obs[1, 7] = np.nan
    with pytest.raises(ObservationError, match=r"\(1, 7\)"):
        check_observation(obs)


def test_observation_needs_a_scene():
    with pytest.raises(ObservationError):
        observation_vector({"ego": None})  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- from the simulator


@pytest.fixture(scope="module")
def dense():
    scenario = get_scenario("four-lane-d3.0")
    env = reset_env(scenario, seed=7)
    for _ in range(3):
        step_env(env, np.array([0.1, 0.0]))
    return scenario, env


def test_scene_has_every_vehicle_in_road_coordinates(dense):
    scenario, env = dense
    sim = env.unwrapped
    scene = scene_from_env(env, scenario)
    assert scene.road == Road(num_lanes=4, lane_width=4.0, first_lane_center=0.0, curvature=0.0)
    assert scene.v_des == scenario.v_des and scene.name == scenario.name
    others = [v for v in sim.road.vehicles if v is not sim.vehicle]
    assert len(scene.neighbours) == len(others) == scenario.vehicles_count
    lane0 = sim.road.network.get_lane(("0", "1", 0))
    for v, n in zip(others, scene.neighbours):
        s, r = lane0.local_coordinates(v.position)
        assert (n.x, n.y) == pytest.approx((s, r))
        assert (n.length, n.width) == (v.LENGTH, v.WIDTH)
        assert n.accel == pytest.approx(v.action["acceleration"], abs=1e-6)  # IDM's, along the velocity
    assert any(n.accel < -0.5 for n in scene.neighbours), "dense traffic has braking vehicles"
    s, r = lane0.local_coordinates(sim.vehicle.position)
    assert (scene.ego.x, scene.ego.y) == pytest.approx((s, r))
    assert scene.ego.length == sim.vehicle.LENGTH


def test_perceived_scene_fills_every_observation_row(dense):
    scenario, env = dense
    perception = perceive(env, scenario)
    obs = observation_vector(perception.scene)
    _, rows = split_observation(obs)
    assert not is_dummy(rows).any()  # 50 vehicles: all ten rows real
    assert neighbour_mask(obs).all() and not neighbour_mask(observation_vector(_scene([]))).any()
    # the planning scene is the simulator's: the ego's velocity along its course (heading + slip)
    assert perception.scene == scene_from_env(env, scenario)
    assert math.hypot(perception.scene.ego.vx, perception.scene.ego.vy) == pytest.approx(abs(perception.kinematics.speed))


def test_actual_vehicle_sizes_reach_the_collision_ellipses():
    scenario = get_scenario("two-lane-d1.0")
    env = reset_env(scenario, seed=1)
    sim = env.unwrapped
    truck = min((v for v in sim.road.vehicles if v is not sim.vehicle), key=lambda v: abs(v.position[0] - sim.vehicle.position[0]))
    truck.LENGTH, truck.WIDTH = 12.0, 2.5  # instance attributes, as upstream's parking env sets them
    scene = scene_from_env(env, scenario)
    index = [n.length for n in scene.neighbours].index(12.0)
    assert scene.neighbours[index].width == 2.5
    problem = build_problem(scene)
    a, b = ellipse_semi_axes(scene.ego, scene.neighbours[index], scene.ellipse_margin)
    assert float(problem.obstacle_a[0]) == pytest.approx(a) and float(problem.obstacle_b[0]) == pytest.approx(b)

    gapped = scene_from_env(env, Task(v_des=scenario.v_des, time_gap=0.4))  # a task's time gap reaches the ellipses
    assert scene.ellipse_margin.time_gap == 0.0 and gapped.ellipse_margin.time_gap == 0.4
    assert float(build_problem(gapped).obstacle_a[0]) == pytest.approx(a + 0.4 * scene.ego.vx)


def _empty(ego_speed=12.0):
    scenario = get_scenario("two-lane-d1.0").replace(vehicles_count=0, ego_speed=ego_speed)
    env = reset_env(scenario, seed=0)
    return scenario, env


def test_ego_velocity_follows_the_course_not_the_body_heading():
    scenario, env = _empty()
    ego = env.unwrapped.vehicle
    ego.heading = 0.05
    ego.action = {"steering": 0.2, "acceleration": 0.0}
    beta = math.atan(0.5 * math.tan(0.2))
    e = scene_from_env(env, scenario).ego
    assert (e.vx, e.vy) == pytest.approx((12.0 * math.cos(0.05 + beta), 12.0 * math.sin(0.05 + beta)))
    assert e.yaw == pytest.approx(0.05)  # the body heading sizes the ego's box in the collision ellipses


def test_ego_acceleration_matches_finite_differences_of_the_simulation():
    scenario, env = _empty()
    action = np.array([0.4, 0.06])  # 2 m/s^2, a gentle left turn
    step_env(env, action)
    before = scene_from_env(env, scenario).ego
    step_env(env, action)
    after = scene_from_env(env, scenario).ego
    dt = 1.0 / scenario.policy_frequency
    assert before.ax == pytest.approx((after.vx - before.vx) / dt, abs=0.05)
    assert before.ay == pytest.approx((after.vy - before.vy) / dt, abs=0.05)
    assert abs(before.ay) > 0.5, "the turn produces a lateral acceleration"


def test_two_way_and_merge_roads_exclude_oncoming_and_ramp_lanes():
    for name in ("two-way", "merge"):
        scenario = get_scenario(name)
        env = reset_env(scenario, seed=0)
        scene = scene_from_env(env, scenario)
        assert scene.road == Road(num_lanes=2, lane_width=4.0, first_lane_center=0.0, curvature=0.0)
        network = env.unwrapped.road.network
        frame = build_frame(network, ("a", "b"))
        for x in (0.0, 250.0, 350.0, 1000.0):  # before, along and after the merge section, past the end
            assert frame.road(x, 30.0, 10.0).num_lanes == 2


def test_merge_obstacle_is_a_neighbour():
    scenario = get_scenario("merge")
    env = reset_env(scenario, seed=0)
    scene = scene_from_env(env, scenario)
    sim = env.unwrapped
    assert len(scene.neighbours) == len(sim.road.vehicles) - 1 + len(sim.road.objects)
    assert any(n.vx == 0.0 and (n.length, n.width) == (2.0, 2.0) for n in scene.neighbours)


def test_non_finite_simulator_state_raises():
    scenario, env = _empty()
    env.unwrapped.vehicle.speed = float("nan")
    with pytest.raises(ObservationError, match="t = 0.00 s"):
        scene_from_env(env, scenario)


def test_uneven_lanes_are_rejected():
    from highway_env.road.lane import StraightLane
    from highway_env.road.road import RoadNetwork

    network = RoadNetwork()
    network.add_lane("a", "b", StraightLane([0, 0], [100, 0], width=4.0))
    network.add_lane("a", "b", StraightLane([0, 5], [100, 5], width=4.0))
    with pytest.raises(RoadFrameError, match="not adjacent"):
        build_frame(network, ("a", "b"))


def test_a_crashed_car_is_perceived_sliding_to_a_stop():
    """highway-env brakes a crashed car to a stop along its heading: the scene predicts it so (the slide of its speed
    x 1 s), not driving on in its lane at its speed as the other cars."""
    scenario = get_scenario("four-lane-d3.0")
    env = reset_env(scenario, seed=7)
    sim = env.unwrapped
    others = [v for v in sim.road.vehicles if v is not sim.vehicle]
    wreck = min(others, key=lambda v: abs(v.position[0] - sim.vehicle.position[0] - 20.0))
    wreck.crashed = True
    scene = scene_from_env(env, scenario)
    paths = [n for n in scene.neighbours if isinstance(n, PathNeighbour)]
    assert len(paths) == 1 and len(scene.neighbours) == len(others)
    lane0 = sim.road.network.get_lane(("0", "1", 0))
    s, _ = lane0.local_coordinates(wreck.position)
    assert paths[0].path_x[0] == pytest.approx(s, abs=1e-6)
    assert paths[0].path_x[-1] - paths[0].path_x[0] == pytest.approx(wreck.speed * np.cos(wreck.heading), rel=0.01)
