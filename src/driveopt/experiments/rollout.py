"""The receding-horizon episode loop in highway-env: ask the driver, step the simulator, record.

    rollout = Rollout(get_scenario("four-lane-d3.0"), get_planner("bilevel").driver(), seed=42)
    for step in rollout:          # before the simulator advances: step.env shows the state
        ...                       # step.decision was made from (draw videos here)
    episode = rollout.episode     # collided, off-road, speeds, planning times, statuses

Every policy step (``scenario.policy_frequency``, 10 Hz by default) the driver
(:mod:`driveopt.drivers`) returns a ``Decision`` (the action, and the plan that takes effect at that step), the
loop yields it, then steps the simulator and records the outcome in :class:`Episode`. Leaving the road does not end
an episode (it is recorded as ``off_road``), unless the car drives on beyond the reach of a driver's road frame
(:data:`driveopt.sim.road_frame.MAX_EGO_OFFSET` beside the lanes): then the episode ends there, off-road. Everything
random derives from the seed: same seed, same episode. :func:`run_episode` runs a whole episode.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Iterator, NamedTuple

import numpy as np

from driveopt.drivers.base import Decision, Driver, DriverSpec
from driveopt.registry import get_planner
from driveopt.sim.env import make_env, step_env
from driveopt.sim.road_frame import RoadFrameError
from driveopt.sim.scenarios import Scenario, get_scenario

RENDER_CONFIG = {"screen_width": 1000, "screen_height": 250, "scaling": 7.0}  # [px], [px], [px/m]


@dataclass
class Episode:
    """What one closed-loop episode did. Times in seconds unless the name says ms."""

    scenario: str
    planner: str
    seed: int
    collided: bool = False
    off_road: bool = False
    sim_duration: float = 0.0  # [s] simulated time reached
    speeds: list[float] = field(default_factory=list)  # [m/s] ego speed after every step
    lateral: list[float] = field(default_factory=list)  # [m] ego y after every step
    plan_ms: list[float] = field(default_factory=list)  # [ms] wall time of every planning call
    compile_seconds: float = 0.0  # wall time of the warm-up planning call (jit compilation)
    sim_seconds: float = 0.0  # wall time spent in the simulator
    plan_seconds: float = 0.0  # wall time spent planning
    statuses: Counter = field(default_factory=Counter)
    guarded: int = 0  # [-] steps whose command the contact guard replaced by braking now
    plan_periods: list[int] = field(default_factory=list)  # [policy periods] after which each plan took effect in real
    # time (driveopt.drivers.latency; the first is 0: the simulator waits for it); empty when the simulator waited

    @property
    def mean_speed(self) -> float:
        return float(np.mean(self.speeds)) if self.speeds else 0.0

    def record(self) -> dict[str, Any]:
        """JSON-ready record (one line of the bench store); ``plan_periods`` only for a real-time episode."""
        record = {
            "collided": self.collided,
            "off_road": self.off_road,
            "mean_speed": self.mean_speed,
            "sim_duration": self.sim_duration,
            "steps": len(self.speeds),
            "plan_ms": [round(v, 2) for v in self.plan_ms],
            "compile_seconds": self.compile_seconds,
            "sim_seconds": self.sim_seconds,
            "plan_seconds": self.plan_seconds,
            "statuses": dict(self.statuses),
            "guarded": self.guarded,
        }
        return {**record, "plan_periods": list(self.plan_periods)} if self.plan_periods else record

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary of ``driveopt drive`` (planning-time median and p95 instead of every time)."""
        plan_ms = np.asarray(self.plan_ms) if self.plan_ms else np.zeros(1)
        return {
            "scenario": self.scenario, "planner": self.planner, "seed": self.seed, "collided": self.collided,
            "off_road": self.off_road, "simulated_s": self.sim_duration, "mean_speed": self.mean_speed,
            "plan_ms_median": float(np.median(plan_ms)), "plan_ms_p95": float(np.percentile(plan_ms, 95)),
            "sim_wall_s": self.sim_seconds, "plan_wall_s": self.plan_seconds, "statuses": dict(self.statuses),
            **self._latency_summary(),
        }

    def _latency_summary(self) -> dict[str, Any]:
        """Median and largest ``plan_periods`` of a real-time episode; nothing when the simulator waited."""
        if not self.plan_periods:
            return {}
        return {"plan_periods_median": float(np.median(self.plan_periods)), "plan_periods_max": max(self.plan_periods)}


class Step(NamedTuple):
    """One policy step, yielded before the simulator advances."""

    env: Any  # the simulator, in the state the decision was made from
    decision: Decision
    episode: Episode  # the running record (up to the previous step)


class Rollout:
    """One closed-loop episode of ``driver`` in ``scenario`` with traffic from ``seed``; iterate it once."""

    def __init__(self, scenario: Scenario | str, driver: Driver, seed: int, *, duration: float | None = None,
                 render: bool = False) -> None:
        scenario = get_scenario(scenario) if isinstance(scenario, str) else scenario
        self.scenario = scenario if duration is None else scenario.replace(duration=float(duration))
        self.driver = driver
        self.seed = seed
        self.render = render
        self.episode = Episode(self.scenario.name, driver.name, seed)

    def __iter__(self) -> Iterator[Step]:
        env = make_env(self.scenario, render_mode="rgb_array" if self.render else None)
        if self.render:
            env.unwrapped.config.update(RENDER_CONFIG)
        episode = self.episode
        try:
            env.reset(seed=self.seed)
            self.driver.reset(env, self.scenario, self.seed)
            episode.compile_seconds = self.driver.compile_seconds
            while True:
                try:
                    decision = self.driver.act(env)
                except RoadFrameError:
                    if not episode.off_road:
                        raise
                    return  # the car left the road and then the reach of the planner's road frame: it ends off-road
                note_decision(episode, decision)
                yield Step(env, decision, episode)
                if advance(env, episode, decision.action):
                    return
        finally:
            env.close()

    def run(self) -> Episode:
        """Drive the whole episode and return its record."""
        for _ in self:
            pass
        return self.episode


def note_decision(episode: Episode, decision: Decision) -> None:
    """Record in ``episode`` what the step's ``decision`` says: its plan's time and status, its latency, its guard."""
    if decision.result is not None:
        episode.plan_ms.append(1e3 * decision.plan_seconds)
        episode.plan_seconds += decision.plan_seconds
        episode.statuses[decision.result.status.name] += 1
    if decision.latency_periods is not None:
        episode.plan_periods.append(decision.latency_periods)
    episode.guarded += decision.guarded


def advance(env: Any, episode: Episode, action: np.ndarray) -> bool:
    """Step the simulator with ``action`` and record the outcome in ``episode``; whether the episode has ended (its
    duration reached, or a collision)."""
    start = time.perf_counter()
    outcome = step_env(env, action)
    episode.sim_seconds += time.perf_counter() - start
    ego = env.unwrapped.vehicle
    episode.speeds.append(float(ego.speed))
    episode.lateral.append(float(ego.position[1]))
    episode.sim_duration = outcome.time
    episode.collided |= outcome.crashed
    episode.off_road |= outcome.off_road
    return bool(outcome.done or outcome.crashed)


def run_episode(scenario: Scenario | str, planner: DriverSpec | str, seed: int, *, duration: float | None = None,
                render: bool = False) -> Episode:
    """Drive one episode of ``planner`` (a registered name or spec) and return its record."""
    spec = get_planner(planner) if isinstance(planner, str) else planner
    return Rollout(scenario, spec.driver(), seed, duration=duration, render=render).run()
