"""driveopt's gymnasium env ids, registered without importing gymnasium, highway-env or JAX at ``import driveopt``.

    import gymnasium, driveopt
    env = gymnasium.make("driveopt/highway-v0", config={"action": {"type": "ContinuousAction"}})
    env = gymnasium.make("driveopt/driving-v0", scenario="four-lane-d1.0")   # the RL baselines' task
    env = gymnasium.make("driveopt/controlled-v0", env="highway-v0", planner="bilevel")   # a controller drives it

Registering an env in gymnasium needs gymnasium (its registry), and importing gymnasium costs about
0.3 s (numpy), more than the rest of ``import driveopt`` and ``driveopt --help``. So :func:`install`
(run by ``import driveopt``) registers at once when gymnasium is already imported, and otherwise adds a
one-shot import hook that registers right after gymnasium's own import finishes: either order of
``import gymnasium`` and ``import driveopt`` works. Entry points are strings: making an env imports its
module (highway-env; for the RL env also JAX), registering does not.

:data:`SPECS` maps each id to its entry point and ``max_episode_steps`` (gymnasium's ``TimeLimit``):

- ``driveopt/highway-v0``, ``driveopt/two-way-v0``, ``driveopt/merge-v0``: the scenario adapters of
  :mod:`driveopt.sim.env`, one per road layout of :data:`ROAD_ENVS` (the one table of the layouts: the scenarios'
  ``road`` values, :data:`driveopt.sim.scenarios.ROADS`, and the ids :data:`ROAD_ENV_IDS` come from it); they
  truncate themselves at their ``duration`` config [s] (no TimeLimit). Made by id they have RL spaces: upstream's
  ``Kinematics`` observation (any ``observation`` config given) and ``ContinuousAction``; driveopt's own loop makes
  them without an observation (:data:`driveopt.sim.env.UNOBSERVED`);
- ``driveopt/driving-v0``: :class:`driveopt.rl.env.DrivingEnv`, one action per second, truncated after
  :data:`RL_EPISODE_STEPS` steps (the default scenario's 50 s; pass ``max_episode_steps`` to
  ``gymnasium.make`` with a scenario of another duration); the env for training an agent on driveopt's scenarios;
- ``driveopt/controlled-v0``: :class:`driveopt.sb3.ControllerEnv`, a highway-env env driven by a driveopt
  controller (its action ignored: ``Discrete(1)``), for evaluating a planner in SB3's ``VecEnv`` s.
"""

from __future__ import annotations

import sys
from typing import Any, NamedTuple


class EnvSpec(NamedTuple):
    entry_point: str  # "module:Class"
    max_episode_steps: int | None  # [steps] gymnasium TimeLimit; None: the env ends its episodes itself


RL_EPISODE_STEPS = 50  # [steps] of 1 s: the RL env's default scenario (two-lane-d1.0) lasts 50 s

ROAD_ENVS: dict[str, str] = {  # road layout -> its adapter env in driveopt.sim.env (over highway-env's <layout>-v0)
    "highway": "DriveoptHighwayEnv",
    "two-way": "DriveoptTwoWayEnv",
    "merge": "DriveoptMergeEnv",
}


def road_env_id(road: str) -> str:
    """The gymnasium id of the adapter env of road layout ``road``: ``driveopt/<road>-v0``, named after upstream's
    ``<road>-v0`` it adapts."""
    return f"driveopt/{road}-v0"


ROAD_ENV_IDS: dict[str, str] = {road: road_env_id(road) for road in ROAD_ENVS}
"""gymnasium id of the adapter env of each road layout."""

SPECS: dict[str, EnvSpec] = {
    **{road_env_id(road): EnvSpec(f"driveopt.sim.env:{env}", None) for road, env in ROAD_ENVS.items()},
    "driveopt/driving-v0": EnvSpec("driveopt.rl.env:DrivingEnv", RL_EPISODE_STEPS),
    "driveopt/controlled-v0": EnvSpec("driveopt.sb3:ControllerEnv", None),
}


def register() -> None:
    """Register every id of :data:`SPECS` not yet in gymnasium's registry (imports gymnasium; idempotent)."""
    import gymnasium

    for env_id, spec in SPECS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=spec.entry_point, max_episode_steps=spec.max_episode_steps)


class _AfterGymnasium:
    """A meta path finder (not importing ``importlib.abc``: 40 ms) that finds nothing itself; when ``gymnasium`` is about to be imported, wraps its loader so that :func:`register`
    runs once the package has executed, then leaves ``sys.meta_path``."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname != "gymnasium":
            return None
        _remove_hook()
        spec = _find_elsewhere(fullname, path, target)
        loader = getattr(spec, "loader", None)
        if loader is None or not hasattr(loader, "exec_module"):
            return spec
        exec_module = loader.exec_module

        def exec_then_register(module: Any) -> None:
            exec_module(module)
            register()  # its ``import gymnasium`` finds the module just executed in sys.modules

        loader.exec_module = exec_then_register  # this loader instance loads only gymnasium's __init__
        return spec


def _find_elsewhere(fullname: str, path: Any, target: Any) -> Any:
    for finder in sys.meta_path:
        find = getattr(finder, "find_spec", None)
        if find is not None:
            spec = find(fullname, path, target)
            if spec is not None:
                return spec
    return None


def _remove_hook() -> None:
    sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, _AfterGymnasium)]


def install() -> None:
    """Register now when gymnasium is imported, else when it is (see the module docstring)."""
    if "gymnasium" in sys.modules:
        register()
    elif not any(isinstance(f, _AfterGymnasium) for f in sys.meta_path):
        sys.meta_path.insert(0, _AfterGymnasium())
