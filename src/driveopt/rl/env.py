"""The RL baselines' training env (P1 §V-A4, App. III) and the behaviour controller it shares with the driver.

    env = DrivingEnv("two-lane-d1.0")        # gymnasium.Env: Discrete(5) -> Box((55,), float32)
    obs, info = env.reset(seed=7)            # same seed, same traffic
    obs, reward, terminated, truncated, info = env.step(FASTER)
    info["reward_terms"]                     # {"collision": ..., "speed": ..., "lane_change": ..., "off_road": ...}

The simulator is the scenario's own env (:func:`driveopt.sim.env.make_env`, same roads, traffic and
seeds as ``drive`` and ``bench``) with ``policy_frequency`` 1 Hz: one action per second (P1 Table II's
policy period). At reset the ego is handed to :class:`BehaviourVehicle`, upstream's
``ControlledVehicle`` (a proportional speed controller and a lateral-position -> heading cascade,
highway-env's ``MDPVehicle`` and every meta-action agent use the same two) with the scenario car's
limits: accelerations within ``scenario.acceleration_range`` (+-5 m/s^2) and steering within
``scenario.steering_range``, as the planners' car. The env's ContinuousAction input is ignored (the
car follows its set-points); the five behaviours of P1 move the set-points:

===========  ======================================================================================
action       set-point change
===========  ======================================================================================
0 LANE_LEFT  target lane - 1 (4 m to the left, lane 0 at y = 0), when that lane exists and is reachable
1 IDLE       none: keep the current speed and lane set-points
2 LANE_RIGHT target lane + 1 (4 m to the right)
3 FASTER     target speed + 5 m/s (at most :data:`MAX_TARGET_SPEED`)
4 SLOWER     target speed - 5 m/s (at least 0)
===========  ======================================================================================

(upstream's DiscreteMetaAction numbering). Why not upstream's ``MDPVehicle``: its FASTER rounds the
*current* speed to a grid and adds one step, so a car slowed by traffic loses its set-point; P1 moves
the set-point by 5 m/s, as ``ControlledVehicle.act`` does, and IDLE keeps both set-points.

Observation: :func:`policy_observation`, the 55-dim :func:`driveopt.observation.observation_vector` of
the perceived scene (the bi-level planner's and the CVAE's input) divided by the fixed per-feature
units :data:`OBSERVATION_SCALE` (lateral offsets in lanes of 4 m, longitudinal offsets in 100 m,
velocities in 20 m/s, headings in rad), so that no input of the network is in the hundreds (a missing
neighbour's padding row sits 1000 m ahead). The scale is a constant, not a running statistic: nothing
to save with a policy, and the driver computes the same vector.

Reward: the weighted sum of the named terms of :class:`RewardWeights` (weights in brackets), each
reported in ``info["reward_terms"]`` as its weighted contribution (they add up to the reward):

- ``collision`` [-1]: 1 on the step the ego collides (the episode ends);
- ``speed`` [0.4]: the ego's speed along the road over the scenario's ``v_des`` (20 m/s), clipped to [0, 1];
- ``lane_change`` [-0.05]: 1 when the action moved the target lane (discourages weaving);
- ``off_road`` [-1]: 1 while the ego's centre is off every lane.

Episodes end on a collision (``terminated``; on ``merge`` also upstream's end past the ramp) or at the
scenario's duration (``truncated``: 50 s, i.e. 50 steps).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import gymnasium as gym
import numpy as np
from highway_env.vehicle.controller import ControlledVehicle

from driveopt.observation import EGO_FEATURES, NEIGHBOUR_FEATURES, NUM_NEIGHBOURS, OBSERVATION_DIM, observation_vector
from driveopt.scene import Scene
from driveopt.sim.env import make_env, sim_time
from driveopt.sim.perception import perceive
from driveopt.sim.scenarios import Scenario, ScenarioError, get_scenario

POLICY_PERIOD = 1.0  # [s] one behaviour decision per second (P1 Table II: policy scheduling time)
SPEED_STEP = 5.0  # [m/s] FASTER / SLOWER move the target speed by this much (P1 App. III)
MAX_TARGET_SPEED = 30.0  # [m/s] highest target speed (six FASTER steps from a standstill)
ACTIONS = ("LANE_LEFT", "IDLE", "LANE_RIGHT", "FASTER", "SLOWER")  # index -> behaviour (upstream's meta-action names)
LANE_LEFT, IDLE, LANE_RIGHT, FASTER, SLOWER = range(len(ACTIONS))
_IGNORED_INPUT = np.zeros(2, dtype=np.float32)  # the ContinuousAction the env steps with; the controller ignores it

# Fixed units of the 55 observation features (see the module docstring and driveopt.observation).
_LANE = 4.0  # [m]
_LONGITUDINAL = 100.0  # [m]
_SPEED = 20.0  # [m/s]
OBSERVATION_SCALE = np.array(
    [_LANE, _LANE, _SPEED, _SPEED, 1.0] + [_LONGITUDINAL, _LANE, _SPEED, _SPEED, 1.0] * NUM_NEIGHBOURS, dtype=np.float32
)
OBSERVATION_BOUND = 100.0  # [-] scaled features are clipped to +-this (10 km along the road, 400 m across, 2000 m/s)
assert OBSERVATION_SCALE.shape == (EGO_FEATURES + NEIGHBOUR_FEATURES * NUM_NEIGHBOURS,) == (OBSERVATION_DIM,)


@dataclasses.dataclass(frozen=True)
class RewardWeights:
    """Weight of each named reward term (see the module docstring for the terms)."""

    collision: float = -1.0  # [-] per collision
    speed: float = 0.4  # [-] per step at v_des or faster
    lane_change: float = -0.05  # [-] per lane-change set-point move
    off_road: float = -1.0  # [-] per step off the road

    def to_dict(self) -> dict[str, float]:
        return dataclasses.asdict(self)


def policy_observation(scene: Scene) -> np.ndarray:
    """(55,) float32: the scene's :func:`~driveopt.observation.observation_vector` in the fixed units of
    :data:`OBSERVATION_SCALE`, clipped to +-:data:`OBSERVATION_BOUND` (what the policies see, in training and in
    the closed loop; no real road reaches the bound)."""
    return np.clip(observation_vector(scene) / OBSERVATION_SCALE, -OBSERVATION_BOUND, OBSERVATION_BOUND)


class BehaviourVehicle(ControlledVehicle):
    """Upstream's set-point tracker with P1's five behaviours and the scenario car's actuator limits.

    ``act(name)`` with a name of :data:`ACTIONS` moves the set-points (target speed kept within
    [0, MAX_TARGET_SPEED] m/s, target lane within the road); ``act()`` or ``act(anything else)`` (the
    env's ContinuousAction) only runs the controllers. Commands are clipped to ``acceleration_range``
    [m/s^2] and ``steering_range`` [rad] before each integration step.
    """

    def __init__(self, road, position, heading: float = 0, speed: float = 0, target_lane_index=None,
                 target_speed: float | None = None, route=None,
                 acceleration_range: tuple[float, float] = (-5.0, 5.0), steering_range: tuple[float, float] = (-math.pi / 4, math.pi / 4)):
        super().__init__(road, position, heading, speed, target_lane_index, target_speed, route)
        self.target_speed = float(target_speed if target_speed is not None else speed)  # upstream's `or` loses 0
        self.acceleration_range = tuple(acceleration_range)
        self.steering_range = tuple(steering_range)

    @classmethod
    def create_from(cls, vehicle: "BehaviourVehicle") -> "BehaviourVehicle":
        return cls(vehicle.road, vehicle.position, vehicle.heading, vehicle.speed, vehicle.target_lane_index,
                   vehicle.target_speed, vehicle.route, vehicle.acceleration_range, vehicle.steering_range)

    def act(self, action: Any = None) -> None:
        if isinstance(action, str) and action in ("FASTER", "SLOWER"):
            step = SPEED_STEP if action == "FASTER" else -SPEED_STEP
            self.target_speed = float(np.clip(self.target_speed + step, 0.0, MAX_TARGET_SPEED))
            action = None
        elif not (isinstance(action, str) and action in ("LANE_LEFT", "LANE_RIGHT")):
            action = None  # IDLE, the env's ContinuousAction, None: track the current set-points
        super().act(action)

    def clip_actions(self) -> None:
        super().clip_actions()
        if not self.crashed:
            self.action["acceleration"] = float(np.clip(self.action["acceleration"], *self.acceleration_range))
            self.action["steering"] = float(np.clip(self.action["steering"], *self.steering_range))


def hand_ego_to_behaviours(env: Any, scenario: Scenario) -> BehaviourVehicle:
    """Replace the env's ego by a :class:`BehaviourVehicle` at the same state, its set-points the current lane
    and speed; return it."""
    sim = env.unwrapped
    ego = sim.vehicle
    lane = sim.road.network.get_closest_lane_index(ego.position, ego.heading)
    car = BehaviourVehicle(sim.road, ego.position, ego.heading, ego.speed, target_lane_index=lane,
                           target_speed=max(float(ego.speed), 0.0), acceleration_range=scenario.acceleration_range,
                           steering_range=scenario.steering_range)
    sim.road.vehicles[sim.road.vehicles.index(ego)] = car
    sim.vehicle = car
    return car


def apply_behaviour(car: BehaviourVehicle, action: int) -> bool:
    """Move ``car``'s set-points by behaviour ``action`` (an index of :data:`ACTIONS`); whether the target lane moved."""
    index = int(action)
    if not 0 <= index < len(ACTIONS):
        raise ValueError(f"action must be an integer in [0, {len(ACTIONS) - 1}], got {action!r}")
    lane = car.target_lane_index
    car.act(ACTIONS[index])
    return car.target_lane_index != lane


def policy_scenario(scenario: Scenario | str) -> Scenario:
    """``scenario`` (or the registered one of that name) with one policy step per :data:`POLICY_PERIOD`."""
    scenario = get_scenario(scenario) if isinstance(scenario, str) else scenario
    frequency = round(1.0 / POLICY_PERIOD)
    if scenario.simulation_frequency % frequency:
        raise ScenarioError(f"simulation_frequency ({scenario.simulation_frequency} Hz) must be a multiple of the "
                            f"RL policy frequency ({frequency} Hz)")
    return scenario.replace(policy_frequency=frequency)


class DrivingEnv(gym.Env):
    """P1's RL task over a driveopt scenario (see the module docstring); observation, action, reward, ends."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": round(1.0 / POLICY_PERIOD)}

    def __init__(self, scenario: Scenario | str = "two-lane-d1.0", *, reward_weights: RewardWeights = RewardWeights(),
                 render_mode: str | None = None) -> None:
        self.scenario = policy_scenario(scenario)
        self.reward_weights = reward_weights
        self.render_mode = render_mode
        self.observation_space = gym.spaces.Box(-OBSERVATION_BOUND, OBSERVATION_BOUND, shape=(OBSERVATION_DIM,), dtype=np.float32)
        self.action_space = gym.spaces.Discrete(len(ACTIONS))
        self._env = make_env(self.scenario, render_mode=render_mode)
        self.car: BehaviourVehicle | None = None

    @property
    def sim(self) -> Any:
        """The highway-env simulator (``env.unwrapped`` of the scenario env)."""
        return self._env.unwrapped

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self._env.reset(seed=seed)
        self.car = hand_ego_to_behaviours(self._env, self.scenario)
        return policy_observation(perceive(self._env, self.scenario).scene), self._info(None, {})

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self.car is None:
            raise RuntimeError("call reset() before step()")
        lane_changed = apply_behaviour(self.car, int(np.asarray(action).item()))
        _, _, upstream_end, truncated, _ = self._env.step(_IGNORED_INPUT)
        scene = perceive(self._env, self.scenario).scene
        crashed, off_road = bool(self.car.crashed), not self.car.on_road
        w = self.reward_weights
        speed = float(np.clip(scene.ego.vx / self.scenario.v_des, 0.0, 1.0)) if self.scenario.v_des > 0 else 0.0
        terms = {  # weighted contributions (+ 0.0: no -0.0 for a term that is off)
            "collision": w.collision * float(crashed) + 0.0,
            "speed": w.speed * speed + 0.0,
            "lane_change": w.lane_change * float(lane_changed) + 0.0,
            "off_road": w.off_road * float(off_road) + 0.0,
        }
        reward = float(sum(terms.values()))
        info = self._info(ACTIONS[int(np.asarray(action).item())], terms)
        return policy_observation(scene), reward, bool(crashed or upstream_end), bool(truncated), info

    def _info(self, behaviour: str | None, terms: dict[str, float]) -> dict[str, Any]:
        car = self.car
        return {
            "behaviour": behaviour,  # the action just applied (None after reset)
            "reward_terms": terms,  # weighted contributions; they add up to the reward
            "crashed": bool(car.crashed),
            "off_road": not car.on_road,
            "speed": float(car.speed),  # [m/s]
            "target_speed": float(car.target_speed),  # [m/s] speed set-point
            "target_lane": int(car.target_lane_index[2]),  # [-] lane set-point (0: leftmost, y = 0)
            "time": sim_time(self._env),  # [s]
        }

    def render(self) -> Any:
        return self._env.render()

    def close(self) -> None:
        self._env.close()
