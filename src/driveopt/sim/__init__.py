"""Closed-loop simulation in upstream highway-env: scenarios, env adapter, road (Frenet) frame, perception, control.

    from driveopt.sim import BicycleModel, get_scenario, make_env, perceive, step_env, to_world, track

    scenario = get_scenario("four-lane-d3.0")
    env = make_env(scenario)
    env.reset(seed=42)
    perception = perceive(env, scenario)               # -> driveopt.problem.build_problem(perception.scene)
    world = to_world(result.trajectory, perception.frame)   # the plan in world coordinates
    command = track(world, 0.0, perception.tracking, BicycleModel.from_env(env))
    outcome = step_env(env, command.action)

This package knows no planner. The episode loop that runs a driver in it is :mod:`driveopt.experiments.rollout`.
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
from driveopt.sim.perception import Perception, RoadPreview, Task, perceive, scene_from_env
from driveopt.sim.rewards import gym_make
from driveopt.sim.road_frame import RoadFrame, RoadFrameError, build_frame, ego_frame
from driveopt.sim.world_plan import WorldTrajectory, to_world
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
    "Perception", "RoadPreview", "Task", "perceive", "scene_from_env",
    "gym_make", "RoadFrame", "RoadFrameError", "build_frame", "ego_frame", "WorldTrajectory", "to_world",
    "Scenario", "ScenarioError", "apply_overrides", "get_scenario", "list_scenarios", "load_overrides",
    "resolve_scenario",
]
