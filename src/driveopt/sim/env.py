"""Thin adapter over upstream highway-env: one registered gymnasium env per road layout.

    env = make_env(get_scenario("four-lane-d3.0"))
    env.reset(seed=42)                       # same seed -> same traffic
    outcome = step_env(env, action)          # action: ContinuousAction in [-1, 1]^2
    outcome.crashed, outcome.off_road, outcome.done

The subclasses below only add what the scenarios need and upstream has no config key for:

- a neighbour speed limit written on every lane (upstream hard-codes 30 m/s on highway-v0),
  and neighbour IDM target speeds drawn in ``target_speed_fraction * speed_limit`` from the
  env's seeded generator, with each neighbour's initial speed set to its target;
- the ego's initial speed (upstream: 25 m/s on highway-v0, 30 m/s on two-way-v0 and merge-v0);
- highway: neighbours shifted ahead so none spawns within ``min_initial_gap`` of the ego, and
  so that same-lane bumper gaps are at least ``min_spawn_gap``: at density 3 upstream spawns
  overlapping cars (6-11 overlapping pairs of 50 on four lanes) and up to half of the
  neighbours crash into each other within 10 s;
- a road that simulates the same, faster (:mod:`driveopt.sim.fast_road`), and in driveopt's own loop no upstream
  observation (``"observation": UNOBSERVED``, :class:`Unobserved`: driveopt perceives from ``env.unwrapped``);
  made by id (``gymnasium.make("driveopt/highway-v0")``) they have real spaces for RL: upstream's ``Kinematics``
  observation (or any observation config given) and ``ContinuousAction`` (Box(-1, 1, (2,)): acceleration, steering);
- truncation after ``duration`` seconds on every road, counted in integer simulation steps
  (upstream accumulates ``1 / policy_frequency`` in a float; two-way-v0 and merge-v0 never truncate);
- rewards that do not read DiscreteMetaAction-only state (upstream two-way-v0 reads
  ``vehicle.speed_index``; merge-v0 tests ``action in [0, 2]``, which raises for array actions): the
  terms of :mod:`driveopt.sim.rewards`, which fixes a user's own env the same way.

gymnasium 1.x wrappers hide attributes: reach the simulator through ``env.unwrapped``.
"""

from __future__ import annotations

import os
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
from highway_env.envs.common.action import action_factory
from highway_env.envs.common.observation import ObservationType
from highway_env.envs.highway_env import HighwayEnv
from highway_env.envs.merge_env import MergeEnv
from highway_env.envs.two_way_env import TwoWayEnv

from driveopt import gym_envs
from driveopt.sim.fast_road import FastRoad
from driveopt.sim.rewards import two_way_rewards
from driveopt.sim.scenarios import Scenario

UPSTREAM_TRAFFIC = "highway_env.vehicle.behavior.IDMVehicle"
FORWARD_TRAFFIC = "driveopt.sim.traffic.ForwardIDMVehicle"
ENV_IDS = gym_envs.ROAD_ENV_IDS
"""gymnasium id of the adapter env of each road layout (:data:`driveopt.gym_envs.ROAD_ENVS` names the classes below)."""


UNOBSERVED = {"type": "Unobserved"}
"""The adapters' ``observation`` config for driveopt's own loop (:func:`env_config`): :class:`Unobserved`."""


class Unobserved(ObservationType):
    """Upstream's observation slot, left empty: driveopt perceives from ``env.unwrapped`` (:mod:`driveopt.sim.perception`)
    and never reads what ``reset`` and ``step`` return, which upstream's cheapest observation (Kinematics, built
    with pandas) made ~10% of a simulator step. ``reset``/``step`` return a constant (1,) array. Only in driveopt's
    own loop (``"observation": UNOBSERVED``): an RL agent needs a real observation."""

    def space(self) -> gym.spaces.Box:
        return gym.spaces.Box(0.0, 0.0, shape=(1,), dtype=np.float32)

    def observe(self) -> np.ndarray:
        return np.zeros(1, np.float32)


class _ScenarioTraffic:
    """Mixin over an upstream env: speed limit, neighbour target speeds, ego speed, duration."""

    def define_spaces(self) -> None:
        if self.config["observation"] != UNOBSERVED:  # type: ignore[attr-defined]
            super().define_spaces()  # type: ignore[misc]
            return
        self.observation_type = Unobserved(self)
        self.action_type = action_factory(self, self.config["action"])  # type: ignore[attr-defined]
        self.observation_space = self.observation_type.space()
        self.action_space = self.action_type.space()

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()  # type: ignore[misc]
        config.update(
            {
                # real spaces when made by id (RL, gymnasium's and SB3's checkers); driveopt's loop: UNOBSERVED
                "observation": {"type": "Kinematics"},  # upstream two-way-v0's TimeToCollision reads discrete speeds
                "action": {"type": "ContinuousAction"},  # the car driveopt's planners drive
                "speed_limit": None,  # [m/s] written on every lane; None keeps upstream's limits
                "target_speed_fraction": (0.7, 0.8),  # [-] neighbour target speed ~ U(lo, hi) * speed_limit
                "ego_initial_speed": None,  # [m/s] None keeps upstream's
                "min_initial_gap": 0.0,  # [m] highway only
                "min_spawn_gap": None,  # [m] highway only; None keeps upstream's spawn positions
                "duration": 40.0,  # [s]
            }
        )
        return config

    def _apply_speed_limit(self) -> None:
        limit = self.config["speed_limit"]
        if limit is None:
            return
        for tos in self.road.network.graph.values():
            for lanes in tos.values():
                for lane in lanes:
                    lane.speed_limit = float(limit)

    def _apply_traffic(self) -> None:
        """Ego initial speed; neighbours' target (and initial) speeds, drawn in road.vehicles order."""
        if self.config["ego_initial_speed"] is not None:
            self.vehicle.speed = float(self.config["ego_initial_speed"])
        limit = self.config["speed_limit"]
        if limit is None:
            return
        lo, hi = self.config["target_speed_fraction"]
        for vehicle in self.road.vehicles:
            if vehicle is not self.vehicle and hasattr(vehicle, "target_speed"):
                vehicle.target_speed = float(self.np_random.uniform(lo * limit, hi * limit))
                vehicle.speed = vehicle.target_speed

    def _is_truncated(self) -> bool:
        steps = round(self.config["duration"] * self.config["simulation_frequency"])
        return self.steps >= steps

    def _reset(self) -> None:
        """Upstream's road and vehicles (two-way, merge) with the scenario's limit and traffic speeds."""
        self._make_road()
        self._apply_speed_limit()
        self._make_vehicles()
        self._apply_traffic()


class DriveoptHighwayEnv(_ScenarioTraffic, HighwayEnv):
    """highway-v0 (straight multi-lane highway, neighbours spawned ahead of the ego) with scenario traffic."""

    def _create_road(self) -> None:
        super()._create_road()
        self.road = FastRoad.like(self.road)  # same simulation, array neighbour search and collision pre-test

    def _reset(self) -> None:
        self._create_road()
        self._apply_speed_limit()  # before spawning: upstream draws initial speeds and gaps from the limit
        self._create_vehicles()
        self._keep_initial_gap()
        self._keep_spawn_gaps()
        self._apply_traffic()

    def _keep_initial_gap(self) -> None:
        """Shift every neighbour forward so that none is within min_initial_gap [m] ahead of the ego."""
        gap = float(self.config["min_initial_gap"])
        others = [v for v in self.road.vehicles if v is not self.vehicle]
        if gap <= 0 or not others:
            return
        lane = self.vehicle.lane
        ego_s = lane.local_coordinates(self.vehicle.position)[0]
        nearest = min(lane.local_coordinates(v.position)[0] - ego_s for v in others)
        if nearest < gap:
            for v in others:
                _move_along(v, lane.direction * (gap - nearest))

    def _keep_spawn_gaps(self) -> None:
        """Per lane, rear to front, push vehicles forward until each bumper gap is >= min_spawn_gap [m].

        Upstream spaces consecutive spawns ~(12 + speed) / density * exp(-5 / 40 * lanes) apart in
        random lanes, which at high density puts cars of the same lane closer than their length.
        """
        gap = self.config["min_spawn_gap"]
        if gap is None:
            return
        by_lane: dict[Any, list] = {}
        for v in self.road.vehicles:
            by_lane.setdefault(v.lane_index, []).append(v)
        for lane_index, vehicles in by_lane.items():
            lane = self.road.network.get_lane(lane_index)
            vehicles.sort(key=lambda v: lane.local_coordinates(v.position)[0])
            for rear, front in zip(vehicles, vehicles[1:]):
                needed = 0.5 * (rear.LENGTH + front.LENGTH) + float(gap)
                actual = lane.local_coordinates(front.position)[0] - lane.local_coordinates(rear.position)[0]
                if actual < needed:
                    _move_along(front, lane.direction * (needed - actual))


def _move_along(vehicle: Any, shift: np.ndarray) -> None:
    vehicle.position = vehicle.position + shift
    vehicle.on_state_update()


class DriveoptTwoWayEnv(_ScenarioTraffic, TwoWayEnv):
    """two-way-v0 (one lane each way; the ego overtakes on the oncoming lane) with scenario traffic."""

    def _rewards(self, action: Any) -> dict[str, float]:
        return two_way_rewards(self, action)


class DriveoptMergeEnv(_ScenarioTraffic, MergeEnv):
    """merge-v0 (2-lane highway with an on-ramp; upstream ends the episode past x = 370 m) with scenario traffic."""

    def _rewards(self, action: Any) -> dict[str, float]:
        # upstream's lane_change_reward tests `action in [0, 2]` (DiscreteMetaAction); no lane-change actions here
        return MergeEnv._rewards(self, None)


def register_envs() -> None:
    """Register driveopt's envs with gymnasium (idempotent; :mod:`driveopt.gym_envs`, which ``import driveopt`` runs)."""
    gym_envs.register()


register_envs()


def env_config(scenario: Scenario) -> dict[str, Any]:
    """highway-env configuration of a scenario (upstream keys plus the adapter's)."""
    config: dict[str, Any] = {
        "action": {
            "type": "ContinuousAction",
            "longitudinal": True,
            "lateral": True,
            "acceleration_range": scenario.acceleration_range,  # [m/s^2]
            "steering_range": scenario.steering_range,  # [rad]
            "clip": True,
        },
        # driveopt builds its own observation from env.unwrapped: none from upstream
        "observation": UNOBSERVED,
        "simulation_frequency": scenario.simulation_frequency,  # [Hz]
        "policy_frequency": scenario.policy_frequency,  # [Hz]
        "duration": scenario.duration,  # [s]
        "speed_limit": scenario.speed_limit,  # [m/s]
        "target_speed_fraction": scenario.target_speed_fraction,  # [-]
        "ego_initial_speed": scenario.ego_speed,  # [m/s]
        # IDM + MOBIL; upstream's may roll backwards when braking hard, driveopt's forward-only one stops at 0 m/s
        "other_vehicles_type": UPSTREAM_TRAFFIC if scenario.traffic_reverses else FORWARD_TRAFFIC,
    }
    if scenario.road == "highway":
        config.update(
            {
                "lanes_count": scenario.lanes,
                "vehicles_count": scenario.vehicles_count,
                "vehicles_density": scenario.density,
                "min_initial_gap": scenario.min_initial_gap,  # [m]
                "min_spawn_gap": scenario.min_spawn_gap,  # [m]
                "offroad_terminal": False,  # off-road is reported, not an episode end
            }
        )
    return config


def make_env(scenario: Scenario, *, render_mode: str | None = None) -> gym.Env:
    """The gymnasium env of a scenario. Reset it with ``env.reset(seed=...)`` before use.

    ``render_mode="rgb_array"`` renders headless: SDL_VIDEODRIVER defaults to ``offscreen``
    (``dummy`` would give black frames).
    """
    if render_mode == "rgb_array":
        os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    return gym.make(ENV_IDS[scenario.road], config=env_config(scenario), render_mode=render_mode, disable_env_checker=True)


class StepOutcome(NamedTuple):
    """What one ``step_env`` call reports."""

    time: float  # [s] simulated time since reset
    crashed: bool  # the ego collided (info["crashed"])
    off_road: bool  # the ego's centre left every lane (not vehicle.on_road)
    terminated: bool  # upstream's terminal condition (crash; merge: past the ramp)
    truncated: bool  # the scenario's duration has elapsed
    info: dict

    @property
    def done(self) -> bool:
        return self.terminated or self.truncated


def sim_time(env: gym.Env) -> float:
    """[s] simulated time since the last reset."""
    u = env.unwrapped
    return u.steps / u.config["simulation_frequency"]


def is_off_road(env: gym.Env) -> bool:
    """Whether the ego's centre is outside its nearest lane (upstream ``vehicle.on_road``)."""
    return not env.unwrapped.vehicle.on_road


def step_env(env: gym.Env, action: np.ndarray) -> StepOutcome:
    """Apply one ContinuousAction (normalised (acceleration, steering) in [-1, 1]) for 1 / policy_frequency s."""
    _, _, terminated, truncated, info = env.step(np.asarray(action, dtype=np.float32))
    return StepOutcome(
        time=sim_time(env),
        crashed=bool(info["crashed"]),
        off_road=is_off_road(env),
        terminated=bool(terminated),
        truncated=bool(truncated),
        info=info,
    )
