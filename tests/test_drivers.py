"""Drivers: the optimiser's adaptation to the simulated car, IDM's hand-over, and one step of each."""

import numpy as np
import pytest

from driveopt.config import ConfigError
from driveopt.drivers.optimiser import adapt_to_vehicle
from driveopt.planner import PlanStatus
from driveopt.registry import get_planner
from driveopt.sim.control import BicycleModel
from driveopt.sim.env import make_env
from driveopt.sim.scenarios import get_scenario


def test_planner_bounds_fit_the_simulated_car():
    scenario = get_scenario("four-lane-d3.0")
    config = adapt_to_vehicle(get_planner("bilevel").config, scenario, BicycleModel())
    assert config.projection.a_max <= 5.0 and config.projection.kappa_max < 2 * np.sin(np.arctan(0.5)) / 5.0
    assert config.qp.initial_acceleration  # plans start from the applied acceleration (smooth commands)


@pytest.fixture
def env_and_scenario():
    scenario = get_scenario("two-lane-d1.0")
    env = make_env(scenario)
    env.reset(seed=4)
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
    from driveopt.sim.rollout import Rollout

    spec = get_planner("grid").with_replan_every(5)
    rollout = Rollout("two-lane-d1.0", spec.driver(), seed=2, duration=1.0)
    planned = [step.decision.result is not None for step in rollout]
    assert planned == [True, False, False, False, False] * 2
    assert len(rollout.episode.plan_ms) == 2 and len(rollout.episode.speeds) == 10
    assert get_planner("idm").with_replan_every(5) == get_planner("idm")
    with pytest.raises(ConfigError, match="replan_every"):
        get_planner("grid").with_replan_every(0)
