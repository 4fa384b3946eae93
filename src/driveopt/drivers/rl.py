"""P1's RL baselines (DQN, PPO; §V-A4) as closed-loop drivers: a learned policy picks a behaviour every second.

The standard loop (``drive``, ``bench``) steps a 10 Hz ContinuousAction env. As ``idm`` does, the
driver hands the ego at reset to a controller vehicle, here the one the policy was trained with
(:class:`driveopt.rl.env.BehaviourVehicle`: upstream's set-point tracker with the scenario car's
limits), and answers every policy step with the idle action, which that vehicle ignores. Every
``POLICY_PERIOD * policy_frequency`` steps (1 s: 10 steps at 10 Hz) it perceives the scene, asks the
policy (deterministic) for one of the five behaviours and moves the set-points; in between the
controller tracks them at the simulation rate. The car, its controller and the observation are those
of the training env (:class:`driveopt.rl.env.DrivingEnv`, 1 Hz), so the policy drives here exactly the
dynamics it learned on; only the decision instants are counted in policy steps instead of env steps.

Policies: ``weights`` (``--weights FILE``), else the one shipped for the road's lane count
(``weights/{dqn|ppo}-{two|four}-lane.zip``); without either, a :class:`~driveopt.rl.policy.PolicyError`
names the command that trains one. Policies trained on another lane count are refused.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

from driveopt.drivers.base import Decision, DriverSpec
from driveopt.drivers.idm import IDLE_ACTION
from driveopt.files import file_digest
from driveopt.rl.policy import PolicyError, cached_policy, check_algo, lane_word, shipped_policy
from driveopt.sim.perception import perceive
from driveopt.sim.scenarios import Scenario

TRAINING_STEPS = 5_000_000  # [-] P1 Table II: what the error message suggests for a shipped policy


def train_command(algo: str, scenario: Scenario) -> str:
    """The command that trains a policy for ``scenario``'s road."""
    folder = f"out/{algo}-{lane_word(scenario.lanes)}-lane"
    return f"driveopt train {algo} --scenario {scenario.name} --steps {TRAINING_STEPS} --out {folder}"


@dataclasses.dataclass(frozen=True)
class RLSpec(DriverSpec):
    """A Stable-Baselines3 policy over P1's five behaviours; see the module docstring."""

    algo: str = "dqn"  # one of driveopt.rl.policy.ALGORITHMS
    weights: str | None = None  # policy file; None: the one shipped for the road's lane count

    def __post_init__(self) -> None:
        check_algo(self.algo)

    @property
    def needs_scenario(self) -> bool:
        """The policy was trained on a driveopt scenario's observation, car and timing, for its lane count."""
        return True

    @property
    def takes_weights(self) -> bool:
        """``weights`` is its policy file."""
        return True

    def check(self, scenario: Scenario) -> None:
        self.policy(scenario)

    def driver(self) -> "RLDriver":
        return RLDriver(self)

    def with_weights(self, weights: str | None) -> "RLSpec":
        """Copy that drives with the policy file ``weights`` (unchanged for ``None``)."""
        return self if weights is None else dataclasses.replace(self, weights=weights)

    def policy_file(self, scenario: Scenario) -> Path:
        """The policy file for ``scenario``'s road; PolicyError naming the training command when there is none."""
        if self.weights:
            return Path(self.weights)
        path = shipped_policy(self.algo, scenario.lanes)
        if path is None:
            folder = f"out/{self.algo}-{lane_word(scenario.lanes)}-lane"
            raise PolicyError(f"no {self.algo} policy shipped for {scenario.lanes}-lane roads: train one with "
                              f"`{train_command(self.algo, scenario)}` and pass --weights {folder}/best.zip "
                              f"(or copy it to src/driveopt/weights/{self.algo}-{lane_word(scenario.lanes)}-lane.zip)")
        return path

    def weights_digest(self, scenario: Scenario) -> str:
        """Digest of the policy file for ``scenario``'s road."""
        return file_digest(self.policy_file(scenario))

    def policy(self, scenario: Scenario) -> Any:
        """The loaded policy for ``scenario``'s road (once per process and file); PolicyError when there is none or it
        is unusable, MissingExtraError without Stable-Baselines3."""
        return cached_policy(self.policy_file(scenario), self.algo, scenario.lanes)


def _policy_env() -> Any:
    """:mod:`driveopt.rl.env`, imported when a driver first runs: it imports gymnasium and highway-env, which the
    registry (and so ``driveopt plan``) should not pay for."""
    from driveopt.rl import env

    return env


class RLDriver:
    """Runs an :class:`RLSpec`'s policy at 1 s period inside the standard rollout (see the module docstring)."""

    def __init__(self, spec: RLSpec) -> None:
        self.spec = spec
        self.name = spec.name
        self.compile_seconds = 0.0
        self.behaviours: list[str] = []  # the behaviour chosen at every decision of the episode

    def reset(self, env: Any, scenario: Scenario, seed: int) -> None:
        """Load the policy (timed as ``compile_seconds``) and hand the ego to the behaviour controller."""
        start = time.perf_counter()
        self.policy = self.spec.policy(scenario)
        self.scenario = scenario
        policy_env = _policy_env()
        self.car = policy_env.hand_ego_to_behaviours(env, scenario)
        self.every = max(1, round(policy_env.POLICY_PERIOD * scenario.policy_frequency))  # [policy steps] between decisions
        self.steps = 0
        self.behaviours = []
        self.compile_seconds = time.perf_counter() - start

    def act(self, env: Any) -> Decision:
        elapsed = 0.0
        if self.steps % self.every == 0:
            start = time.perf_counter()
            policy_env = _policy_env()
            action, _ = self.policy.predict(policy_env.policy_observation(perceive(env, self.scenario).scene), deterministic=True)
            policy_env.apply_behaviour(self.car, int(action))
            self.behaviours.append(policy_env.ACTIONS[int(action)])
            elapsed = time.perf_counter() - start
        self.steps += 1
        return Decision(IDLE_ACTION, plan_seconds=elapsed)
