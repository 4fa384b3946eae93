"""Control inversion: action mapping, exactness against upstream's integrator, open-loop tracking."""

from __future__ import annotations

import math

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import reset_env
from highway_env.vehicle.kinematics import Vehicle

from driveopt.config import BasisConfig, PlannerConfig, QPConfig
from driveopt.planner import PlanStatus, plan
from driveopt.problem import build_problem
from driveopt.qp import boundary_values, make_model, solve_setpoint_qp
from driveopt.sim.control import (
    BicycleModel,
    Command,
    ControlError,
    EgoKinematics,
    brake_at_least,
    command_from_env,
    from_action,
    predict,
    sample_trajectory,
    steering_for_slip,
    to_action,
    track,
)
from driveopt.sim.env import step_env
from driveopt.sim.perception import scene_from_env
from driveopt.sim.road_frame import slip_angle
from driveopt.sim.scenarios import get_scenario
from driveopt.trajectory import Trajectory, evaluate

# ----------------------------------------------------------------------------- the model and the action map


@pytest.fixture(scope="module")
def empty_env():
    scenario = get_scenario("two-lane-d1.0").replace(vehicles_count=0, ego_speed=15.0)
    env = reset_env(scenario, seed=0)
    return scenario, env


def test_model_is_read_from_the_env(empty_env):
    _, env = empty_env
    model = BicycleModel.from_env(env)
    assert model.length == Vehicle.LENGTH == 5.0
    assert model.acceleration_range == (-5.0, 5.0)
    assert model.steering_range == pytest.approx((-math.pi / 4, math.pi / 4))
    assert (model.simulation_dt, model.steps_per_action, model.action_period) == pytest.approx((0.05, 2, 0.1))


def test_discrete_action_env_is_rejected():
    env = gym.make("highway-v0", config={"vehicles_count": 1}, disable_env_checker=True)
    with pytest.raises(ControlError, match="ContinuousAction"):
        BicycleModel.from_env(env)


@pytest.mark.parametrize("simulation_hz, policy_hz, message", [
    (10, 20, "policy_frequency (20 Hz) is above its simulation_frequency (10 Hz): the simulation frequency must be at "
             "least the policy frequency"),
    (15, 0, "policy_frequency must be a finite number > 0 Hz, got 0 (simulation_frequency 15 Hz, policy_frequency 0 Hz)"),
])
def test_frequencies_out_of_order_are_named(simulation_hz, policy_hz, message):
    """A policy faster than the simulation holds each action for no simulation step: the error names both frequencies
    and which must be the larger, not the model's derived fields."""
    env = gym.make("highway-v0", config={"action": {"type": "ContinuousAction"}, "vehicles_count": 1,
                                         "simulation_frequency": simulation_hz, "policy_frequency": policy_hz},
                   disable_env_checker=True)
    with pytest.raises(ControlError) as raised:
        BicycleModel.from_env(env)
    assert message in str(raised.value)


@pytest.mark.parametrize("acceleration, steering", [(0.0, 0.0), (3.2, -0.3), (-5.0, math.pi / 4), (-1.7, 0.05)])
def test_action_mapping_inverts_upstreams(empty_env, acceleration, steering):
    _, env = empty_env
    model = BicycleModel.from_env(env)
    action = to_action(acceleration, steering, model)
    assert np.all(np.abs(action) <= 1.0)
    upstream = env.unwrapped.action_type.get_action(action)
    assert upstream["acceleration"] == pytest.approx(acceleration, abs=1e-5)
    assert upstream["steering"] == pytest.approx(steering, abs=1e-6)
    assert from_action(action, model) == pytest.approx((acceleration, steering), abs=1e-5)


def test_fallback_brakes_at_once_but_not_past_standstill():
    model = BicycleModel()  # acceleration range (-5, 5) m/s^2, 0.1 s action period
    gentle = Command(-1.0, 0.02, to_action(-1.0, 0.02, model), False)
    hard = brake_at_least(gentle, 3.0, model, speed=10.0)
    assert hard.acceleration == -3.0 and hard.steering == 0.02
    np.testing.assert_allclose(from_action(hard.action, model), (-3.0, 0.02), atol=1e-6)
    assert brake_at_least(gentle, 9.0, model, speed=10.0).acceleration == model.acceleration_range[0]
    coasting = Command(0.0, 0.0, to_action(0.0, 0.0, model), False)
    assert brake_at_least(coasting, 3.0, model, speed=0.05).acceleration == pytest.approx(-0.5)  # stops, no reversing
    stronger = Command(-4.0, 0.0, to_action(-4.0, 0.0, model), False)
    assert brake_at_least(stronger, 3.0, model, speed=10.0) is stronger


def test_asymmetric_ranges_and_clipping():
    model = BicycleModel(acceleration_range=(-8.0, 2.0), steering_range=(-0.5, 0.25))
    np.testing.assert_allclose(to_action(-3.0, -0.125, model), [0.0, 0.0])
    np.testing.assert_allclose(to_action(50.0, -9.0, model), [1.0, -1.0])


@pytest.mark.parametrize("delta", [-0.7, -0.1, 0.0, 0.3, 0.78])
def test_steering_for_slip_inverts_the_slip_angle(delta):
    assert steering_for_slip(slip_angle(delta)) == pytest.approx(delta, abs=1e-12)


@pytest.mark.parametrize("speed, heading, acc, steer", [(15.0, 0.0, 2.0, 0.1), (8.0, -0.2, -4.0, -0.6), (22.0, 0.1, 0.0, 0.02)])
def test_predict_reproduces_upstream_integration_exactly(speed, heading, acc, steer):
    model = BicycleModel(steps_per_action=3, simulation_dt=1 / 15)
    vehicle = Vehicle(None, [0.0, 0.0], heading=heading, speed=speed)
    vehicle.act({"acceleration": acc, "steering": steer})
    for _ in range(model.steps_per_action):
        vehicle.step(model.simulation_dt)
    displacement, after = predict(EgoKinematics(speed, heading), acc, steer, model)
    np.testing.assert_allclose(displacement, vehicle.position, atol=1e-12)
    assert (after.speed, after.heading) == pytest.approx((vehicle.speed, vehicle.heading), abs=1e-12)


# ----------------------------------------------------------------------------- track()


def _arc(speed: float, curvature: float, duration: float = 15.0, nodes: int = 100) -> Trajectory:
    """Constant-speed circular arc from the origin, initially along +x."""
    t = np.linspace(0.0, duration, nodes)
    chi = speed * curvature * t
    if curvature == 0.0:
        x, y = speed * t, 0.0 * t
    else:
        x, y = np.sin(chi) / curvature, (1.0 - np.cos(chi)) / curvature
    vx, vy = speed * np.cos(chi), speed * np.sin(chi)
    w = speed * curvature
    ax, ay = -w * vy, w * vx
    zero = 0.0 * t
    return Trajectory(t, x, y, vx, vy, ax, ay, speed + zero, chi, curvature + zero, zero)


def test_straight_constant_speed_plan_gives_a_neutral_action():
    model = BicycleModel()
    command = track(_arc(15.0, 0.0), 0.3, EgoKinematics(15.0, 0.0), model)
    assert (command.acceleration, command.steering) == pytest.approx((0.0, 0.0), abs=1e-9)
    np.testing.assert_allclose(command.action, [0.0, 0.0], atol=1e-7)
    assert not command.saturated


def test_steady_turn_converges_to_the_continuous_inverse():
    model = BicycleModel()
    speed, curvature = 12.0, 0.02
    trajectory = _arc(speed, curvature)
    beta_ss = math.asin(curvature * model.length / 2)  # psi_dot = v sin(beta) / (L/2) = v * curvature
    state, position, t = EgoKinematics(speed, 0.0), np.zeros(2), 0.0
    for _ in range(30):
        command = track(trajectory, t, state, model)
        step, state = predict(state, command.acceleration, command.steering, model)  # step: road frame [m]
        position = position + step
        t += model.action_period
    assert command.steering == pytest.approx(steering_for_slip(beta_ss), rel=1e-3)
    planned = sample_trajectory(trajectory, t)
    assert np.hypot(position[0] - planned.x, position[1] - planned.y) < 0.02


def test_one_step_per_action_hands_the_next_plan_the_planned_course():
    """One simulation step per action (lane-keeping-v0's 10 Hz simulation and policy): the course after the step (the
    heading turned, the slip held), which the next plan starts from, is the planned course at the period's end."""
    model = BicycleModel(simulation_dt=0.1, steps_per_action=1)
    trajectory = _arc(12.0, 0.02)
    state = EgoKinematics(12.0, 0.0)
    for k in range(30):
        command = track(trajectory, 0.1 * k, state, model)
        _, state = predict(state, command.acceleration, command.steering, model)
        planned = sample_trajectory(trajectory, 0.1 * (k + 1))
        assert state.heading + slip_angle(command.steering) == pytest.approx(math.atan2(planned.vy, planned.vx), abs=1e-9)


def test_infeasible_braking_is_clipped_and_flagged():
    model = BicycleModel()
    command = track(_arc(5.0, 0.0), 0.0, EgoKinematics(15.0, 0.0), model)  # 15 -> 5 m/s within 0.1 s
    assert command.saturated and command.acceleration == -5.0 and command.action[0] == -1.0


@pytest.mark.parametrize(
    "mutate, fragment",
    [
        (lambda tr: tr._replace(vx=np.full(100, np.nan)), "NaN"),
        (lambda tr: tr._replace(x=np.zeros((3, 100))), "1-D"),
        (lambda tr: tr._replace(t=tr.t[::-1].copy()), "increase"),
    ],
)
def test_bad_trajectories_raise(mutate, fragment):
    with pytest.raises(ControlError, match=fragment):
        track(mutate(_arc(10.0, 0.0)), 0.0, EgoKinematics(10.0, 0.0), BicycleModel())


def test_hermite_sampling_is_exact_for_cubics():
    t = np.linspace(0.0, 3.0, 7)
    x, vx = t**3 - 2 * t, 3 * t**2 - 2
    zero = 0.0 * t
    trajectory = Trajectory(t, x, zero, vx, zero, 6 * t, zero, vx, zero, zero, zero)
    q = np.array([0.1, 1.23, 2.9])
    np.testing.assert_allclose(sample_trajectory(trajectory, q).x, q**3 - 2 * q, atol=1e-12)


# ----------------------------------------------------------------------------- open-loop tracking in highway-env


def _follow(env, scenario, trajectory, seconds=1.0):
    """Track ``trajectory`` open-loop (planned once, at t = 0); per-step (dx, dy, dspeed) errors and saturation."""
    model = BicycleModel.from_env(env)
    errors, saturated, t = [], False, 0.0
    for _ in range(round(seconds / model.action_period)):
        command = command_from_env(env, trajectory, t, model)
        saturated |= command.saturated
        t = step_env(env, command.action).time
        ego = scene_from_env(env, scenario).ego
        planned = sample_trajectory(trajectory, t)
        errors.append((ego.x - planned.x, ego.y - planned.y, ego.speed - math.hypot(planned.vx, planned.vy)))
    return np.abs(np.array(errors)), saturated


def test_open_loop_lane_change_and_speed_change_tracks_within_6_cm():
    scenario = get_scenario("two-lane-d1.0").replace(vehicles_count=0, ego_speed=15.0)
    env = reset_env(scenario, seed=0)
    ego = scene_from_env(env, scenario).ego
    target_lane = 4.0 if ego.y < 2.0 else 0.0
    qp = QPConfig()
    model = make_model(BasisConfig(), qp)
    b_x, b_y = boundary_values(jnp.array([0.0, ego.vx, ego.ax]), jnp.array([ego.y, ego.vy, ego.ay]), qp)
    setpoints = jnp.array([18.0, 20.0, 20.0, 20.0] + [target_lane] * 4)  # speed up while changing lanes
    coeffs = solve_setpoint_qp(model, setpoints[None], b_x[None], b_y[None])[0]
    trajectory = Trajectory(*(np.asarray(a, dtype=float) for a in evaluate(model, coeffs)))
    trajectory = trajectory._replace(x=trajectory.x + ego.x)
    assert np.ptp(trajectory.y[:20]) > 2.0, "the plan changes lanes within the first 3 s"

    errors, saturated = _follow(env, scenario, trajectory)
    assert not saturated
    # measured: longitudinal 0.053 m (upstream moves with the pre-step speed: lag of a * h / 2 per second
    # of acceleration), lateral 0.004 m, speed 0.01 m/s
    assert errors[:, 0].max() < 0.06
    assert errors[:, 1].max() < 0.01
    assert errors[:, 2].max() < 0.02
    assert abs(scene_from_env(env, scenario).ego.y - ego.y) > 0.2, "the ego really moved sideways"


def test_open_loop_tracking_of_a_planner_result():
    scenario = get_scenario("two-lane-d1.0").replace(vehicles_count=0, ego_speed=10.0)
    env = reset_env(scenario, seed=1)
    scene = scene_from_env(env, scenario)
    config = PlannerConfig().replace(sampler={"num_samples": 250}, projection={"a_max": 4.5})  # inside the 5 m/s^2 action range
    problem = build_problem(scene, config.basis)
    result = plan(problem, config, key=jax.random.PRNGKey(0), x_offset=scene.ego.x)
    assert result.status == PlanStatus.SUCCESS
    errors, saturated = _follow(env, scenario, result.trajectory)
    assert not saturated
    # measured 0.086 m, almost all longitudinal lag (h / 2 * speed gained = 0.025 s * 3.4 m/s)
    assert np.hypot(errors[:, 0], errors[:, 1]).max() < 0.12
    assert scene_from_env(env, scenario).ego.speed > scene.ego.speed + 0.5, "the plan speeds up towards v_des"
