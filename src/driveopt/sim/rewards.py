"""Upstream rewards that accept continuous (array) actions, in subclasses of upstream's envs.

Some of highway-env's rewards read state that only its discrete meta-actions create, and raise on a
``ContinuousAction`` env's array action, already in the ``reset`` that ``gymnasium.make`` runs:

- merge-v0 and roundabout-v0 test ``action in [0, 2]`` (a lane-change action), which raises for an array;
- two-way-v0 reads ``vehicle.speed_index`` and ``vehicle.target_lane_index``, which only upstream's
  ``MDPVehicle`` has;
- lane-keeping-v0's ``step`` records the ego's dynamical state (``BicycleVehicle.state``, for its interval
  plots), which the kinematic ``Vehicle`` of ``ContinuousAction`` without ``dynamical`` does not have (nor does its
  observation's ``state``: make it with ``"observation": {"type": "Kinematics"}``).

:func:`gym_make` is ``gymnasium.make`` for such an env id with the env class replaced by a subclass whose reward
terms read the continuous car (no lane-change action, the speed reward from the speed, the lane reward from the
lane the car is on; lane-keeping-v0 records no dynamical state for a kinematic car); upstream's classes are
untouched, and every other env id is made as it is::

    env = driveopt.gym_make("merge-v0", config={"action": {"type": "ContinuousAction"}})
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache
from typing import Any

import gymnasium as gym
import numpy as np
from highway_env import utils
from highway_env.envs.lane_keeping_env import LaneKeepingEnv
from highway_env.envs.merge_env import MergeEnv
from highway_env.envs.roundabout_env import RoundaboutEnv
from highway_env.envs.two_way_env import TwoWayEnv

TWO_WAY_SPEED_RANGE = (20.0, 30.0)  # [m/s] upstream two-way-v0's target speeds: reward 0 at the lowest, 1 at the highest


def two_way_rewards(env: Any, action: Any) -> dict[str, float]:
    """two-way-v0's reward terms for any ego: speed scaled over :data:`TWO_WAY_SPEED_RANGE`, the left-lane term from
    the lane the car is on."""
    speed = utils.lmap(env.vehicle.speed, list(TWO_WAY_SPEED_RANGE), [0.0, 1.0])
    side = env.road.network.all_side_lanes(env.vehicle.lane_index)
    left = (len(side) - 1 - env.vehicle.lane_index[2]) / max(len(side) - 1, 1)
    return {"high_speed_reward": float(np.clip(speed, 0.0, 1.0)), "left_lane_reward": float(left)}


class ArrayActionRewards:
    """Mixin over an upstream env (first in the bases): its reward terms for array actions."""

    def _rewards(self, action: Any) -> dict[str, float]:
        if isinstance(self, TwoWayEnv):
            return two_way_rewards(self, action)
        return super()._rewards(None if isinstance(action, np.ndarray) else action)  # type: ignore[misc]


class KinematicEgoRecord:
    """Mixin over upstream's LaneKeepingEnv (first in the bases): its ``step`` records the ego's state only for a
    dynamical ego (``BicycleVehicle``), the one with a state to record."""

    def store_data(self) -> None:
        if hasattr(self.vehicle, "state"):  # type: ignore[attr-defined]
            super().store_data()  # type: ignore[misc]


AFFECTED = (MergeEnv, RoundaboutEnv, TwoWayEnv, LaneKeepingEnv)
"""Upstream env classes whose rewards (lane-keeping-v0: whose ``step``) raise on array actions of a kinematic car."""


@lru_cache(maxsize=None)
def with_array_action_rewards(cls: type) -> type:
    """``cls`` itself, or for a subclass of :data:`AFFECTED` a subclass of it with :class:`ArrayActionRewards` (with
    :class:`KinematicEgoRecord` for lane-keeping-v0)."""
    if not issubclass(cls, AFFECTED) or issubclass(cls, (ArrayActionRewards, KinematicEgoRecord)):
        return cls
    mixin = KinematicEgoRecord if issubclass(cls, LaneKeepingEnv) else ArrayActionRewards
    return type(cls.__name__, (mixin, cls), {"__module__": __name__})


def gym_make(env_id: str, **kwargs: Any) -> gym.Env:
    """``gymnasium.make(env_id, **kwargs)`` with the env class given :class:`ArrayActionRewards` where upstream's
    rewards raise on array actions (see the module docstring); the same spec otherwise (wrappers, episode steps)."""
    spec = gym.spec(env_id)
    entry = spec.entry_point
    cls = gym.envs.registration.load_env_creator(entry) if isinstance(entry, str) else entry
    if isinstance(cls, type):
        spec = dataclasses.replace(spec, entry_point=with_array_action_rewards(cls))
    return gym.make(spec, **kwargs)
