"""Episodes in lock-step: E episodes of one arm (scenario and planner) step together in one process, and every policy
step makes one planning call for all of them (:func:`driveopt.multi_plan.plan_many`), so that an accelerator or a
big CPU gets a batch E times larger per call.

    run_lockstep(jobs, options, append, 8)                       # in this process, records as episodes end
    cells(jobs, slots)                                           # the jobs cut into cells, one Ray task each

Each slot holds one episode: its simulator, its driver (:class:`driveopt.drivers.optimiser.OptimiserDriver`) and its
record. A policy step asks every driver for the call it starts (``prepare``: some drivers start none, with
``replan_every`` > 1), solves them in one call padded to ``slots`` (one compilation per arm), hands each driver its
result (``finish``) and steps the simulators one after another. An episode that ends is handed to ``finished`` at
once and its slot takes the arm's next job. Every episode keeps its own PRNG key, warm start and previous plan: same
seed, same statuses and collisions as the one-by-one loop, and trajectories that agree to the float32 rounding of a
batched call (tests/experiments/test_lockstep.py), which the sampler can turn into another pick between near-equal
candidates late in an episode.

Records are those of the one-by-one loop (:func:`driveopt.experiments.bench.episode_record`) with ``lockstep``: the
slot count. Their ``plan_ms`` are the wall times of the shared calls (what each episode waited; the summaries leave
them out of planning times, and plan-time verdicts pair only records of one slot count), and
``compile_seconds`` is the arm's compilation, recorded with the episodes it waited for (0 for the later ones).

Lock-step is valid only for drivers whose steps do not depend on the planning time: optimiser drivers with
synchronous latency (``replan_every`` is the arm's, shared by its episodes); :func:`check_lockstep` refuses others.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import jax

from driveopt.drivers.base import DriverSpec
from driveopt.drivers.optimiser import OptimiserDriver, OptimiserSpec
from driveopt.errors import DriveoptError
from driveopt.experiments.arms import planner_spec, provenance
from driveopt.experiments.rollout import Episode, advance, note_decision
from driveopt.experiments.store import JobKey
from driveopt.files import pytree_digest
from driveopt.multi_plan import plan_many
from driveopt.sim.env import make_env
from driveopt.sim.road_frame import RoadFrameError
from driveopt.sim.scenarios import resolve_scenario

CELL_ROUNDS = 4  # [-] a Ray cell holds this many jobs per slot: its slots refill from its own jobs


class LockstepError(DriveoptError):
    """A lock-step run that cannot be: a planner whose steps depend on its planning time, or a slot count below 1."""


def check_lockstep(spec: DriverSpec, slots: int) -> None:
    """LockstepError unless ``slots`` is an integer >= 1 and ``spec`` is an optimiser planner with synchronous
    latency (its driver's steps do not depend on how long a call takes)."""
    if isinstance(slots, bool) or not isinstance(slots, int) or slots < 1:
        raise LockstepError(f"lockstep must be an integer >= 1 (episodes per planning call), got {slots!r}")
    if not isinstance(spec, OptimiserSpec) or type(spec.driver()) is not OptimiserDriver:
        raise LockstepError(f"planner {spec.name} cannot run in lock-step: only optimiser planners can (leave "
                            f"{spec.name} out, or run without --lockstep)")
    if spec.latency.realtime:
        raise LockstepError(f"planner {spec.name} with latency {spec.latency.option} cannot run in lock-step: its steps "
                            "depend on each call's own planning time (use synchronous latency, or run without --lockstep)")


def cells(jobs: Sequence[JobKey], slots: int, rounds: int = CELL_ROUNDS) -> list[list[JobKey]]:
    """``jobs`` cut into cells of one arm each (scenario and planner, in the jobs' order), of at most ``slots`` x
    ``rounds`` jobs: one lock-step run (a Ray task) each."""
    arms: dict[tuple[str, str], list[JobKey]] = {}
    for job in jobs:
        arms.setdefault((job.scenario, job.planner), []).append(job)
    size = slots * rounds
    return [arm[i:i + size] for arm in arms.values() for i in range(0, len(arm), size)]


class _Slot:
    """One running episode: its simulator, driver and record."""

    def __init__(self, job: JobKey, spec: OptimiserSpec, scenario: Any) -> None:
        self.job = job
        self.env = make_env(scenario)
        self.driver = spec.driver()
        self.episode = Episode(scenario.name, spec.name, job.env_seed)
        try:
            self.env.reset(seed=job.env_seed)
            self.driver.reset(self.env, scenario, job.env_seed, warm_up=False)
        except BaseException:
            self.env.close()
            raise
        shared = self.driver.shared()
        # the calls of slots with one group are solved together: the same configuration, method, prior and filter
        parts = [shared.prior, shared.safety_filter]
        self.group = (shared.config, shared.method, str(jax.tree_util.tree_structure(parts)), pytree_digest(parts))

    def close(self) -> None:
        self.env.close()


def run_lockstep(jobs: Sequence[JobKey], options: dict[str, Any], finished: Callable[[dict[str, Any]], None] | None,
                 slots: int) -> list[dict[str, Any]]:
    """Run ``jobs`` (any arms; each arm's in turn) ``slots`` episodes at a time, in this process, and hand each record
    to ``finished`` as its episode ends (in completion order). Returns the records when ``finished`` is None (a Ray
    task's answer), else []. ``options``: the bench options (:func:`driveopt.experiments.bench.episode_record`)."""
    kept: list[dict[str, Any]] = []
    for arm in cells(jobs, slots, rounds=max(len(jobs), 1)):
        spec = planner_spec(arm[0].planner, options)
        check_lockstep(spec, slots)
        scenario = resolve_scenario(arm[0].scenario, overrides=options.get("scenario"))
        if options.get("duration") is not None:
            scenario = scenario.replace(duration=float(options["duration"]))
        deliver = finished or kept.append
        run_arm(arm, spec, scenario, slots, lambda job, episode: deliver(_record(job, episode, slots)))
    return kept


def _record(job: JobKey, episode: Episode, slots: int) -> dict[str, Any]:
    """The bench record of ``job``'s ``episode``: the one-by-one loop's fields, and ``lockstep``."""
    return {**episode.record(), **provenance(), "lockstep": slots, **job._asdict()}


def run_arm(jobs: Sequence[JobKey], spec: OptimiserSpec, scenario: Any, slots: int,
            deliver: Callable[[JobKey, Episode], None]) -> None:
    """The episodes of ``jobs`` (of ``spec`` on ``scenario``, a Scenario with its duration), ``slots`` at a time;
    ``deliver(job, episode)`` as each ends. Its traffic seed is the job's ``env_seed``."""
    queue = deque(jobs)
    live: list[_Slot] = []
    compiled: set[Any] = set()
    try:
        while queue or live:
            waiting = []  # slots filled at this step: they carry the compilation they waited for
            while queue and len(live) < slots:
                live.append(_Slot(queue.popleft(), spec, scenario))
                waiting.append(live[-1])
            compile_seconds = _compile(live, slots, compiled)
            for slot in waiting:
                slot.episode.compile_seconds = compile_seconds
            ended = _step(live, slots)
            for slot in ended:
                live.remove(slot)
                slot.close()
                deliver(slot.job, slot.episode)
    finally:
        for slot in live:
            slot.close()


def _compile(live: list[_Slot], slots: int, compiled: set[Any]) -> float:
    """Compile the batched call of every group of ``live`` not compiled yet (each slot's warm-up call, padded to
    ``slots``; the results are discarded); [s] its wall time."""
    start = time.perf_counter()
    for slot in live:
        if slot.group not in compiled:
            compiled.add(slot.group)
            shared = slot.driver.shared()
            plan_many([slot.driver.warm_up_call()], shared.config, prior=shared.prior, safety_filter=shared.safety_filter,
                      method=shared.method, slots=slots)
    return time.perf_counter() - start


def _step(live: list[_Slot], slots: int) -> list[_Slot]:
    """One policy step of every episode of ``live``: one planning call per group of the slots that start one, then
    each simulator stepped. Returns the slots whose episode ended."""
    ended: list[_Slot] = []
    calls: dict[Any, list[tuple[_Slot, Any]]] = {}
    for slot in live:
        try:
            call = slot.driver.prepare(slot.env)
        except RoadFrameError:
            if not slot.episode.off_road:
                raise
            ended.append(slot)  # beyond the reach of the road frame after leaving the road: it ends off-road
            continue
        if call is not None:
            calls.setdefault(slot.group, []).append((slot, call))
    results: dict[int, tuple[Any, float]] = {}
    for group in calls.values():
        shared = group[0][0].driver.shared()
        start = time.perf_counter()
        solved = plan_many([call for _, call in group], shared.config, prior=shared.prior,
                           safety_filter=shared.safety_filter, method=shared.method, slots=slots)
        seconds = time.perf_counter() - start
        results.update({id(slot): (result, seconds) for (slot, _), result in zip(group, solved)})
    for slot in live:
        if slot in ended:
            continue
        result, seconds = results.get(id(slot), (None, 0.0))
        try:
            decision = slot.driver.finish(slot.env, result, seconds)
        except RoadFrameError:
            if not slot.episode.off_road:
                raise
            ended.append(slot)
            continue
        note_decision(slot.episode, decision)
        if advance(slot.env, slot.episode, decision.action):
            ended.append(slot)
    return ended
