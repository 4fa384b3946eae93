"""Who acts in the closed loop: the :class:`Driver` protocol, what one step decides, and the spec that makes a driver.

A driver is reset once per episode (``reset(env, scenario, seed)``: it may swap the ego vehicle,
compile, draw its PRNG key from the seed) and then asked for one action per policy step
(``act(env) -> Decision``). The rollout (:mod:`driveopt.experiments.rollout`) owns the simulator; a driver
only reads it and answers. A :class:`DriverSpec` is the registered, immutable description of a
planner (``driveopt planners``) and makes a fresh driver for each episode.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Mapping, NamedTuple, Protocol

import numpy as np

from driveopt.checks import ConfigError
from driveopt.errors import DriveoptError
from driveopt.planner import PlanResult
from driveopt.problem import PlanningProblem
from driveopt.scene import Scene


class Decision(NamedTuple):
    """What a driver decided at one policy step."""

    action: np.ndarray  # (2,) highway-env ContinuousAction in [-1, 1]^2 (acceleration, steering)
    result: PlanResult | None = None  # the result of the planning call that takes effect at this step, else None
    scene: Scene | None = None  # the scene it planned in
    problem: PlanningProblem | None = None  # the planning problem it solved
    plan_seconds: float = 0.0  # [s] wall time of the planning call
    guarded: bool = False  # the contact guard replaced the command by braking now (driveopt.sim.contact)
    frame: Any = None  # the road frame it planned in (driveopt.sim.road_frame.RoadFrame)
    plan_world: Any = None  # the plan it follows in world coordinates (driveopt.sim.world_plan.WorldTrajectory)
    latency_periods: int | None = None  # [policy periods] from the step the delivered plan started to this one (None:
    # the simulator waited for it, driveopt.drivers.latency)
    plan_index: int | None = None  # which planning call of the episode (from 0) the action tracks; None: no plan
    plan_elapsed: float = 0.0  # [s] how far into that plan (from the state it was made from) the action tracks it


class Driver(Protocol):
    name: str
    compile_seconds: float  # [s] wall time of the warm-up in ``reset`` (jit compilation); 0 when none

    def reset(self, env: Any, scenario: Any, seed: int) -> None:
        ...

    def act(self, env: Any) -> Decision:
        ...


@dataclasses.dataclass(frozen=True)
class DriverSpec:
    """A registered planner: its name, a one-line description, and how to make its driver.

    The ``with_*`` copies change what an optimiser plans with; they leave drivers without an
    optimiser (``idm``) unchanged, so that one bench option can apply to every planner.
    """

    name: str
    description: str

    @property
    def is_optimiser(self) -> bool:
        return False

    @property
    def needs_scenario(self) -> bool:
        """Whether its driver needs a driveopt scenario (its car, timing and lane count) rather than any highway-env
        env with a task (:class:`driveopt.sim.perception.Task`): False by default."""
        return False

    @property
    def takes_weights(self) -> bool:
        """Whether ``with_weights`` changes what it drives with (a learned prior's checkpoint, a policy file): False
        by default, and for optimisers whose prior is not learned (``bilevel``'s Gaussian, the grids)."""
        return False

    def driver(self) -> Driver:
        raise NotImplementedError

    def check(self, scenario: Any) -> None:
        """Raise the user-facing error that a driver would raise in ``reset`` on ``scenario`` (missing,
        unusable or wrong-road weights), before any episode starts; nothing to check by default."""

    def weights_digest(self, scenario: Any) -> str | None:
        """A digest of the learned weights this planner drives with on ``scenario``'s road (given or shipped),
        so that a bench folder can refuse to mix episodes of two sets of weights; None when it uses none."""
        return None

    def config_digest(self) -> str | None:
        """A digest of the configuration this planner plans with, its defaults included, so that a bench folder can
        refuse to mix episodes planned before and after a default changed; None when it has none."""
        return None

    def with_samples(self, samples: int | None) -> "DriverSpec":
        return self

    def with_overrides(self, **sections: Any) -> "DriverSpec":
        return self

    def with_weights(self, weights: str | None) -> "DriverSpec":
        return self

    def with_filter_weights(self, weights: str | None) -> "DriverSpec":
        return self

    def with_replan_every(self, periods: int | None) -> "DriverSpec":
        return self

    def with_latency(self, latency: Any) -> "DriverSpec":
        return self


def with_samples_and_config(spec: DriverSpec, samples: int | None, overrides: Mapping[str, Any]) -> DriverSpec:
    """``spec`` at ``samples`` per sampler iteration (None: its own) with the config ``overrides`` (nested sections)
    applied after; ConfigError where the overrides' ``sampler.num_samples`` names another count than ``samples``, so
    that neither is silently dropped."""
    sampler = overrides.get("sampler")
    given = sampler.get("num_samples") if isinstance(sampler, Mapping) else None
    if samples is not None and given is not None and given != samples:
        raise ConfigError(f"{samples} samples and the config's sampler.num_samples = {given!r} disagree: give one of them")
    return spec.with_samples(samples).with_overrides(**overrides)


class WeightsError(DriveoptError):
    """A weights file that is not a regular file, or weights given to a planner that takes none."""


def check_weights_file(path: str | Path | None, what: str = "weights") -> None:
    """WeightsError naming ``path`` unless it is None or a regular file: a checkpoint is read only when a driver is
    reset, so a mistyped path would otherwise fail late, or never for a planner that reads no checkpoint."""
    if path is None:
        return
    if not Path(path).exists():
        raise WeightsError(f"{what} file {path} does not exist")
    if not Path(path).is_file():
        raise WeightsError(f"{what} file {path} is not a regular file")


def check_given_weights(spec: DriverSpec, weights: str | Path | None = None,
                        filter_weights: str | Path | None = None) -> None:
    """WeightsError unless the weights a user gave for the one planner ``spec`` (the Controller, ``driveopt plan``,
    ``driveopt drive``) are regular files it uses: ``weights`` for a planner that :attr:`~DriverSpec.takes_weights`,
    ``filter_weights`` (a learned safety filter's checkpoint) for an optimiser. Weights a planner takes no use of are
    refused, not ignored: a run without them is not the run asked for. (``bench`` applies one weights option to a list
    of planners and refuses it only when none of them takes weights.)"""
    check_weights_file(weights)
    check_weights_file(filter_weights, "filter weights")
    if weights is not None and not spec.takes_weights:
        raise WeightsError(f"planner {spec.name} takes no weights (its prior is not learned): leave the weights out, "
                           "or pick a learned planner (`driveopt planners`)")
    if filter_weights is not None and not spec.is_optimiser:
        raise WeightsError(f"planner {spec.name} takes no filter weights (it does not plan with the optimiser)")
