"""Closed-loop simulation in upstream highway-env: scenarios, env adapter, road (Frenet) frame, perception, control.

    from driveopt.sim import BicycleModel, get_scenario, make_env, perceive, step_env, to_world, track

    scenario = get_scenario("four-lane-d3.0")
    env = make_env(scenario)
    env.reset(seed=42)
    perception = perceive(env, scenario)               # -> driveopt.problem.build_problem(perception.scene)
    world = to_world(result.trajectory, perception.frame)   # the plan in world coordinates
    command = track(world, 0.0, perception.tracking, BicycleModel.from_env(env))
    outcome = step_env(env, command.action)

Names are imported on first use, so that ``import driveopt.sim.scenarios`` loads no highway-env. This package
knows no planner. The episode loop that runs a driver in it is :mod:`driveopt.experiments.rollout`.
"""

from driveopt.lazy import lazy_exports

# Module -> the public names it defines, imported on first use.
_MODULES = {
    "driveopt.sim.control": (
        "BicycleModel", "Command", "ControlError", "EgoKinematics", "command_from_env", "ego_kinematics",
        "sample_trajectory", "track",
    ),
    "driveopt.sim.env": ("ENV_IDS", "StepOutcome", "env_config", "is_off_road", "make_env", "sim_time", "step_env"),
    "driveopt.sim.perception": ("Perception", "RoadPreview", "Task", "perceive", "scene_from_env"),
    "driveopt.sim.rewards": ("gym_make",),
    "driveopt.sim.road_frame": ("RoadFrame", "RoadFrameError", "build_frame", "ego_frame"),
    "driveopt.sim.world_plan": ("WorldTrajectory", "to_world"),
    "driveopt.sim.scenarios": (
        "Scenario", "ScenarioError", "apply_overrides", "get_scenario", "list_scenarios", "load_overrides",
        "resolve_scenario",
    ),
}
_EXPORTS = {name: module for module, names in _MODULES.items() for name in names}
__all__ = list(_EXPORTS)


__getattr__, __dir__ = lazy_exports("driveopt.sim", _EXPORTS, globals())
