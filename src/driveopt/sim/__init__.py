"""Closed-loop simulation in upstream highway-env: scenarios, env adapter, observation, control.

    from driveopt.sim import get_scenario, make_env, scene_from_env, command_from_env, step_env

    scenario = get_scenario("four-lane-d3.0")
    env = make_env(scenario)
    env.reset(seed=42)
    scene = scene_from_env(env, scenario)            # -> driveopt.problem.build_problem(scene)
    command = command_from_env(env, result.trajectory, elapsed=0.0)
    outcome = step_env(env, command.action)
"""

from driveopt.sim.control import (
    BicycleModel,
    Command,
    ControlError,
    EgoKinematics,
    command_from_env,
    ego_kinematics,
    sample_trajectory,
    track,
)
from driveopt.sim.env import ENV_IDS, StepOutcome, env_config, is_off_road, make_env, sim_time, step_env
from driveopt.sim.observation import (
    OBSERVATION_DIM,
    ObservationError,
    observation_from_env,
    observation_vector,
    scene_from_env,
)
from driveopt.sim.mpc import Episode, adapt_to_vehicle, run_episode
from driveopt.sim.road_frame import RoadFrameError
from driveopt.sim.scenarios import (
    Scenario,
    ScenarioError,
    apply_overrides,
    get_scenario,
    list_scenarios,
    load_overrides,
    resolve_scenario,
)

__all__ = [
    "BicycleModel", "Command", "ControlError", "EgoKinematics", "command_from_env", "ego_kinematics", "sample_trajectory",
    "track",
    "ENV_IDS", "StepOutcome", "env_config", "is_off_road", "make_env", "sim_time", "step_env",
    "OBSERVATION_DIM", "ObservationError", "observation_from_env", "observation_vector", "scene_from_env",
    "Episode", "adapt_to_vehicle", "run_episode",
    "RoadFrameError",
    "Scenario", "ScenarioError", "apply_overrides", "get_scenario", "list_scenarios", "load_overrides",
    "resolve_scenario",
]
