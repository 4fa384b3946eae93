"""Drivers: the optimiser's adaptation to the simulated car, IDM's hand-over, and one step of each;
what the P1-faithful specs execute and predict."""

from types import SimpleNamespace

import numpy as np
import pytest
from conftest import lane_change, reset_env

from driveopt.checks import ConfigError
from driveopt.drivers.optimiser import DRIVEOPT_LOOP, PAPERS_LOOP, ClosedLoop, OptimiserSpec, adapt_to_vehicle
from driveopt.planner import PlanResult, PlanStatus
from driveopt.prediction import BRAKING_TIME, SELECTION_TIME
from driveopt.problem import build_problem
from driveopt.registry import get_planner
from driveopt.scene import EgoState, Neighbour, Road, Scene
from driveopt.sim.control import BicycleModel, EgoKinematics, brake_at_least, track
from driveopt.sim.scenarios import get_scenario
from driveopt.trajectory import Trajectory


def test_planner_bounds_fit_the_simulated_car():
    scenario = get_scenario("four-lane-d3.0")
    config = adapt_to_vehicle(get_planner("bilevel").config, BicycleModel(acceleration_range=scenario.acceleration_range, steering_range=scenario.steering_range))
    assert config.projection.a_max <= 5.0 and config.projection.kappa_max < 2 * np.sin(np.arctan(0.5)) / 5.0
    assert config.qp.initial_acceleration  # plans start from the applied acceleration (smooth commands)


@pytest.fixture
def env_and_scenario():
    scenario = get_scenario("two-lane-d1.0")
    env = reset_env(scenario, seed=4)
    yield env, scenario
    env.close()


def test_optimiser_driver_plans_from_the_current_state_and_returns_a_valid_action(env_and_scenario):
    env, scenario = env_and_scenario
    driver = get_planner("grid").driver()
    driver.reset(env, scenario, seed=4)
    assert driver.compile_seconds > 0
    decision = driver.act(env)
    assert decision.action.shape == (2,) and np.all(np.abs(decision.action) <= 1.0)
    assert decision.result.status in tuple(PlanStatus) and decision.plan_seconds > 0
    ego = env.unwrapped.vehicle
    assert abs(decision.scene.ego.x - ego.position[0]) < 1e-6  # planned from where the car is


def test_idm_driver_takes_over_the_ego(env_and_scenario):
    from highway_env.vehicle.behavior import IDMVehicle

    env, scenario = env_and_scenario
    driver = get_planner("idm").driver()
    driver.reset(env, scenario, seed=4)
    assert isinstance(env.unwrapped.vehicle, IDMVehicle) and env.unwrapped.vehicle.target_speed == scenario.v_des
    assert driver.act(env).result is None


def test_replan_every_executes_each_plan_for_several_periods():
    """P1's protocol: plan, track the same plan open-loop for the next periods, plan again."""
    from driveopt.experiments.rollout import Rollout

    spec = get_planner("grid").with_replan_every(5)
    rollout = Rollout("two-lane-d1.0", spec.driver(), seed=2, duration=1.0)
    planned = [step.decision.result is not None for step in rollout]
    assert planned == [True, False, False, False, False] * 2
    assert len(rollout.episode.plan_ms) == 2 and len(rollout.episode.speeds) == 10
    assert get_planner("idm").with_replan_every(5) == get_planner("idm")
    with pytest.raises(ConfigError, match="replan_every"):
        get_planner("grid").with_replan_every(0)


def _straight(accel: float, speed: float = 10.0) -> Trajectory:
    """Along the road from x = 0 at ``speed`` [m/s], accelerating at ``accel`` [m/s^2] (never reversing)."""
    t = np.linspace(0.0, 15.0, 301)
    v = np.maximum(speed + accel * t, 0.0)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    a = np.where(v > 0.0, accel, 0.0)
    zero = np.zeros_like(t)
    return Trajectory(t=t, x=x, y=zero + 4.0, vx=v, vy=zero, ax=a, ay=zero, speed=v, heading=zero, curvature=zero, acceleration=a)


@pytest.mark.parametrize("status", [PlanStatus.INFEASIBLE, PlanStatus.NUMERICAL_ERROR])
def test_p1_driver_executes_its_plan_unless_it_is_not_finite(status):
    """executes_infeasible (P1): an INFEASIBLE plan is tracked as it is; on NUMERICAL_ERROR the fallback is
    followed with the brake-now of every other driver (which also brakes on INFEASIBLE)."""
    chosen, fallback = _straight(1.0), _straight(-1.0)  # the stop eases in; the driver brakes at 3 m/s^2 at once
    result = PlanResult(**dict.fromkeys(PlanResult._fields))._replace(
        status=status, trajectory=chosen, fallback=fallback, fallback_deceleration=3.0)
    model, state = BicycleModel(), EgoKinematics(speed=10.0, heading=0.0)
    env = SimpleNamespace(unwrapped=SimpleNamespace(vehicle=SimpleNamespace(speed=10.0)))
    follows_plan = track(chosen, 0.0, state, model)
    brakes_now = brake_at_least(track(fallback, 0.0, state, model), 3.0, model, 10.0)
    assert follows_plan.acceleration > 0.0 and brakes_now.acceleration == pytest.approx(-3.0)

    actions = {}
    for name in ("grid", "grid-p1"):
        driver = get_planner(name).driver()
        driver.model = model
        actions[name] = driver._command(result, driver.followed(result), 0.0, state, env)[0].action  # a road along +x: world
    np.testing.assert_array_equal(actions["grid"], brakes_now.action)
    expected = follows_plan if status == PlanStatus.INFEASIBLE else brakes_now
    np.testing.assert_array_equal(actions["grid-p1"], expected.action)


def test_p1_driver_predicts_neighbours_at_constant_velocity():
    """A leader braking at 4 m/s^2: braking-aware by default, straight on at its current speed without."""
    leader = Neighbour(x=30.0, y=4.0, vx=10.0, accel=-4.0)
    scene = Scene(ego=EgoState(x=5.0, y=4.0, vx=10.0), road=Road(num_lanes=2), neighbours=(leader,), v_des=15.0)
    rows = {}
    for name in ("grid", "grid-p1"):
        spec = get_planner(name)
        driver = spec.driver()
        driver.config = spec.config
        rows[name] = np.asarray(driver._problem(scene).obstacle_x[0])
    t = np.linspace(0.0, spec.config.basis.horizon, spec.config.basis.num_nodes)
    np.testing.assert_allclose(rows["grid-p1"], 25.0 + 10.0 * t, rtol=1e-6, atol=1e-4)  # planning frame: ego at x = 0
    assert rows["grid"][-1] == pytest.approx(25.0 + 12.5, abs=1e-3)  # stopped 12.5 m on
    assert (get_planner("grid").braking_time, get_planner("grid-p1").braking_time) == (BRAKING_TIME, 0.0)
    np.testing.assert_allclose(build_problem(scene, braking_time=0.0).obstacle_x[0], rows["grid-p1"], rtol=1e-6)


@pytest.mark.parametrize("field", ["warm_start", "fixed_batch", "learned_filter", "learned_prior"])
def test_optimiser_spec_flags_must_be_bools(field):
    with pytest.raises(ConfigError, match=field):
        OptimiserSpec("x", "y", **{field: 1})


def test_the_planners_that_take_weights_are_those_that_read_a_checkpoint():
    """--weights is refused for the others (driveopt.drivers.base.check_given_weights): their priors read none."""
    from driveopt.registry import list_planners

    taking = {name for name in list_planners() if get_planner(name).takes_weights}
    learned = {"cvae", "cvae-mix", "vqvae", "vqvae-filter", "vqvae-cem", "cvae-filter", "cvae-multipliers"}
    assert taking == learned | {f"{name}-faithful" for name in learned - {"cvae-mix", "vqvae-cem"}} | {"dqn", "ppo"}


@pytest.mark.parametrize("field", ["executes_infeasible", "braking_prediction", "approach_selection", "contact_guard",
                                   "target_lanes", "commits_at_crossings"])
def test_closed_loop_flags_must_be_bools(field):
    with pytest.raises(ConfigError, match=f"loop.{field}"):
        ClosedLoop(**{field: 1})


def test_the_closed_loop_is_driveopts_by_default_and_the_papers_in_one_value():
    """driveopt's loop executes the safe trajectory (committing to an infeasible plan at crossings), predicts braking
    and each car's lateral motion to its target lane, ranks neighbours by approach, guards; the papers' turns all six
    off, at the given replanning period (P1's -p1 baselines: 5, the faithful planners: 1)."""
    assert OptimiserSpec("x", "y").loop == DRIVEOPT_LOOP == ClosedLoop(1, False, True, True, True)
    assert DRIVEOPT_LOOP.target_lanes and DRIVEOPT_LOOP.commits_at_crossings
    assert ClosedLoop.papers(5) == ClosedLoop(5, executes_infeasible=True, braking_prediction=False,
                                              approach_selection=False, contact_guard=False, target_lanes=False,
                                              commits_at_crossings=False)
    assert PAPERS_LOOP == ClosedLoop.papers(1)
    assert (DRIVEOPT_LOOP.braking_time, DRIVEOPT_LOOP.selection_time) == (BRAKING_TIME, SELECTION_TIME)
    assert (PAPERS_LOOP.braking_time, PAPERS_LOOP.selection_time) == (0.0, 0.0)
    with pytest.raises(ConfigError, match="replan_every"):
        ClosedLoop(replan_every=0)


def test_an_infeasible_plan_is_followed_only_at_crossings_and_only_where_it_meets_the_traffic_later_than_the_stop():
    """A car stands 20 m ahead of the ego at 12 m/s: the stop touches it, a change to the next lane at that speed does
    not. Reported INFEASIBLE with that change chosen, the car follows the change where the car ahead is crossing
    traffic (a PathNeighbour: it stops for nothing off its own lane) and the loop commits at crossings; in lane
    traffic, with the papers' loop, for a SUCCESS or for a chosen plan that meets the car sooner, as before."""
    import dataclasses

    import jax.numpy as jnp

    from driveopt.drivers.optimiser import OptimiserDriver
    from driveopt.fallback import stop_trajectory
    from driveopt.prediction import PathNeighbour
    from driveopt.qp import make_model

    ego = EgoState(x=0.0, y=4.0, vx=12.0)
    standing = PathNeighbour(x=20.0, y=4.0, t=(0.0, 15.0), path_x=(20.0, 20.0), path_y=(4.0, 4.0), path_yaw=(0.0, 0.0))
    crossing = Scene(ego=ego, road=Road(num_lanes=4), neighbours=(standing,))
    lanes = dataclasses.replace(crossing, neighbours=(Neighbour(x=20.0, y=4.0),))
    problem = build_problem(crossing)
    model = make_model()

    def result(y_end, status=PlanStatus.INFEASIBLE):  # what _commits reads of a PlanResult, a lane change chosen
        return SimpleNamespace(status=status, trajectory=lane_change(model, problem, 12.0, y_end, 0.8), fallback=stop,
                               x_offset=0.0, safe_trajectory=stop)

    stop = stop_trajectory(problem, jnp.asarray(model.t), 3.0, "hold")
    change, on = result(8.0), result(4.0)
    driver = OptimiserDriver(get_planner("bilevel"))
    assert driver._commits(change, crossing, problem)
    assert driver.followed(change, commits=True) is change.trajectory and driver.followed(change) is stop
    assert not driver._commits(on, crossing, problem)
    assert not driver._commits(change, lanes, build_problem(lanes))
    assert not driver._commits(result(8.0, PlanStatus.SUCCESS), crossing, problem)
    papers = OptimiserDriver(dataclasses.replace(get_planner("bilevel"), loop=PAPERS_LOOP))
    assert not papers._commits(change, crossing, problem)


# ---------------------------------------------------------------------------------------------- frames that jump


def _carrying_driver(warm, previous):
    """bilevel's driver holding a carried warm start and previous plan made in the frame ``"old"``."""
    from driveopt.drivers.optimiser import OptimiserDriver

    driver = OptimiserDriver(get_planner("bilevel"))
    driver.config, driver.carries_plan = driver.spec.config, True
    driver.warm, driver.previous, driver._carried_frame = warm, previous, "old"
    return driver


def _frame(d_of_car):
    """A frame that puts the car at lateral coordinate ``d_of_car`` [m] (None: it does not reach the car)."""
    return SimpleNamespace(ego_s=0.0, locate=lambda position, near_s=None: None if d_of_car is None else (5.0, d_of_car))


def test_a_carried_plan_moves_with_the_jump_of_the_frames_lateral_origin():
    """On racetrack-v0 the frame along the next piece measures d from another line (the car's d jumped from 0.15 to
    120.11 m): the carried lateral set-points and positions move by that jump, the speeds stay, and a frame that does
    not jump leaves them as they were; one that no longer reaches the car drops them."""
    from driveopt.planner import PreviousPlan

    warm = np.array([10, 10, 11, 11, 0.0, 0.5, 4.0, 4.0], np.float32)
    previous = PreviousPlan(warm.copy(), np.linspace(0.15, 4.0, 100, dtype=np.float32), np.True_)
    env = SimpleNamespace(unwrapped=SimpleNamespace(vehicle=SimpleNamespace(position=np.zeros(2))))

    def perception(frame, ego_y):
        return SimpleNamespace(frame=frame, scene=SimpleNamespace(ego=SimpleNamespace(y=ego_y)))

    driver = _carrying_driver(warm, previous)
    driver._carried_frame = _frame(0.15)
    new = _frame(120.11)
    driver._carry_into(env, perception(new, 120.11))
    assert np.allclose(driver.warm, [10, 10, 11, 11, 119.96, 120.46, 123.96, 123.96])
    assert np.allclose(driver.previous.setpoints, driver.warm)
    assert np.allclose(driver.previous.lateral, previous.lateral + 119.96)
    assert driver._carried_frame is new
    driver._carry_into(env, perception(_frame(120.11), 120.11))  # the next frame along the same piece: no jump
    assert np.allclose(driver.warm[4:], [119.96, 120.46, 123.96, 123.96])

    driver = _carrying_driver(warm, previous)
    driver._carried_frame = _frame(None)
    driver._carry_into(env, perception(_frame(3.0), 3.0))
    assert driver.warm is None and not bool(driver.previous.present)


@pytest.mark.slow  # compiles the planner for another road: about 25 s
def test_racetrack_plans_keep_their_speed_where_the_frame_jumps():
    """racetrack-v0 seed 0: at 6.8 s the car's d jumps from 0.15 to 120.11 m. The plans made right after the jump
    keep the car's speed (with the old frame's lateral set-points carried as they were, the first plan after the jump
    braked to 7.8 m/s, and the one after the jump at 12.6 s to 4.9 m/s)."""
    import driveopt

    env = driveopt.gym_make("racetrack-v0", config={"action": {"type": "ContinuousAction"}})
    env.reset(seed=0)
    ctrl = driveopt.Controller("bilevel", verbose=False)
    ctrl.reset(env, seed=0)
    previous_y, jumps = None, 0
    for _ in range(40):  # 8 s at 5 Hz
        env.step(ctrl.act(env))
        scene = ctrl.driver._perception.scene
        if previous_y is not None and abs(scene.ego.y - previous_y) > 50.0:
            jumps += 1
            assert float(np.min(np.asarray(ctrl.planned.result.trajectory.vx))) > 9.0
        previous_y = scene.ego.y
    assert jumps == 1
