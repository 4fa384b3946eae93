"""``driveopt collect``: expert demonstrations from the bi-level planner in closed loop (P1 §III-D).

The expert is the ``bilevel`` planner as ``drive`` and ``bench`` run it, 250 samples by default (P1's expert used a
large batch; with 1000 samples it crashed in 2 of the first 7 four-lane episodes, which the 250-sample planner
finishes: docs/findings/cvae.md). Every planning step of every episode is
stored (:mod:`driveopt.data.demonstrations`), with up to ``modes`` distinct feasible plans of the
expert's first and final batches (:mod:`driveopt.data.modes`, schema version 2); episodes run in parallel worker
processes and the parent appends each one as it finishes, so a rerun with the same file skips
finished episodes and an interruption loses only the episodes in flight.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from tqdm import tqdm

from driveopt.basis import make_basis
from driveopt.checks import ConfigError, check_count, check_number
from driveopt.config import BasisConfig
from driveopt.data.demonstrations import (
    MAX_MODES,
    MODE_FIELDS,
    ROW_FIELDS,
    DatasetError,
    DemonstrationWriter,
    EpisodeKey,
    mode_distribution,
)
from driveopt.data.modes import select_modes
from driveopt.drivers.optimiser import OptimiserSpec
from driveopt.experiments.rollout import Rollout
from driveopt.experiments.runner import compile_ahead, compile_notice, execute
from driveopt.experiments.store import JobKey, seed_range_problem
from driveopt.files import lock_output_file
from driveopt.observation import OBSERVATION_DIM
from driveopt.registry import get_optimiser
from driveopt.sim.scenarios import get_scenario

EXPERT = "expert"  # planner field of the jobs


def expert_spec(samples: int, iterations: int) -> OptimiserSpec:
    """The bi-level planner with ``samples`` per batch and ``iterations`` sampler iterations."""
    return get_optimiser("bilevel").with_samples(samples).with_overrides(sampler={"num_iterations": iterations})


def demonstration_episode(job: JobKey, options: dict[str, Any]) -> dict[str, Any]:
    """Worker entry point: one expert episode as {"entry": episode fields, "rows": ROW_FIELDS and MODE_FIELDS arrays}."""
    scenario = get_scenario(job.scenario)
    spec = expert_spec(int(options["samples"]), int(options["iterations"]))
    max_modes = int(options.get("modes", MAX_MODES))
    basis, tolerance = make_basis(spec.config.basis), spec.config.sampler.residual_tolerance
    rows: dict[str, list] = {name: [] for name in (*ROW_FIELDS, *MODE_FIELDS)}
    rollout = Rollout(scenario, spec.driver(), job.env_seed, duration=options.get("duration"))
    for step in rollout:
        problem, result = step.decision.problem, step.decision.result
        modes = select_modes((result.first, result.last), problem, basis, tolerance, max_modes)
        for name, values in zip(MODE_FIELDS, modes):
            rows[name].append(values)
        executed = result.safe_trajectory
        rows["observation"].append(np.asarray(problem.observation))
        rows["init_x"].append(np.asarray(problem.init_x))
        rows["init_y"].append(np.asarray(problem.init_y))
        rows["lane_bounds"].append([float(problem.y_lb), float(problem.y_ub)])
        rows["setpoints"].append(np.asarray(result.setpoints))
        rows["coeffs"].append(np.asarray(result.coeffs))
        rows["trajectory"].append(np.stack([executed.x - result.x_offset, executed.y], axis=-1))
        rows["status"].append(int(result.status))
        rows["time"].append(len(rows["time"]) / scenario.policy_frequency)
    episode = rollout.episode
    dtypes = {"status": np.int8, "mode_mask": np.bool_}
    arrays = {name: np.asarray(values, dtype=dtypes.get(name, np.float32)) for name, values in rows.items()}
    entry = {"scenario": job.scenario, "seed": job.seed, "episode": job.episode, "env_seed": job.env_seed,
             "collided": bool(episode.collided), "duration": float(episode.sim_duration)}
    return {"entry": entry, "rows": arrays, "plan_seconds": episode.plan_seconds, "sim_seconds": episode.sim_seconds,
            "compile_seconds": episode.compile_seconds}


def check_options(scenarios: Sequence[str], *, seed: int, episodes: int, samples: int, iterations: int,
                  duration: float, workers: int, modes: int = MAX_MODES) -> None:
    """ConfigError (ScenarioError for an unknown scenario) unless the scenarios are registered, episodes, samples,
    iterations, workers and modes are integers >= 1, the seed is an integer whose episodes' traffic seeds lie in the
    simulator's range (:func:`driveopt.experiments.store.seed_range_problem`) and duration is finite and > 0 [s]."""
    if not scenarios:
        raise ConfigError("collect needs at least one scenario")
    for name in scenarios:
        get_scenario(name)
    check_count("seed", seed, 0)
    for name, value in (("episodes", episodes), ("samples", samples), ("iterations", iterations), ("workers", workers),
                        ("modes", modes)):
        check_count(name, value)
    problem = seed_range_problem(seed, episodes)
    if problem:
        raise ConfigError(problem)
    check_number("duration", duration, 0.0, low_open=True, unit="s")


def collect(
    out: str | Path,
    scenarios: Sequence[str],
    *,
    seed: int = 7,
    episodes: int = 10,
    samples: int = 250,
    iterations: int = 5,
    duration: float = 50.0,
    workers: int = 1,
    modes: int = MAX_MODES,
    progress: bool = True,
) -> dict[str, Any]:
    """Append the missing expert episodes (scenarios x episodes, traffic from ``seed``) to ``out``, each
    row with up to ``modes`` modes of the expert's first and final batches.

    Returns a summary: episodes and rows written now, skipped as already present, wall time, and
    ``modes_per_row`` ({"k": rows written now with k modes}).
    Options are checked (:func:`check_options`) before the file is created or opened; the run holds a lock beside
    the file (``.NAME.lock``), so a second collection into the same file is refused at once (OutputInUseError).
    """
    check_options(scenarios, seed=seed, episodes=episodes, samples=samples, iterations=iterations,
                  duration=duration, workers=workers, modes=modes)
    basis = BasisConfig()
    settings = {"expert": "bilevel", "samples": samples, "iterations": iterations, "duration": float(duration),
                "num_nodes": basis.num_nodes, "horizon": basis.horizon, "modes": modes}
    # Episode-major: a collection stopped part-way covers every scenario evenly.
    jobs = [JobKey(s, EXPERT, seed, e) for e in range(episodes) for s in scenarios]
    summary = {"episodes": 0, "rows": 0, "collided": 0, "skipped": 0, "plan_seconds": 0.0, "sim_seconds": 0.0}
    start = time.perf_counter()
    out = _output_file(out)
    with lock_output_file(out):
        writer = DemonstrationWriter(out, settings, basis.num_nodes, 2 * (basis.order + 1), OBSERVATION_DIM, modes)
        options = {"samples": samples, "iterations": iterations, "duration": duration, "modes": modes}
        _collect_into(writer, jobs, options, workers, progress, summary)
    summary["wall_seconds"] = time.perf_counter() - start
    summary["settings"] = settings
    return summary


def _output_file(out: str | Path) -> Path:
    """``out`` as a Path, its folder created; DatasetError when it is a folder or its folder cannot be made."""
    path = Path(out)
    if path.is_dir():
        raise DatasetError(f"{path} is a directory; give the demonstrations file's path (e.g. {path / 'demonstrations.h5'})")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DatasetError(f"cannot create the folder of {path}: {exc.strerror or exc}") from None
    return path


def _collect_into(writer: DemonstrationWriter, jobs: list[JobKey], options: dict[str, Any], workers: int, progress: bool,
                  summary: dict[str, Any]) -> None:
    """Run the jobs ``writer``'s file lacks (each episode with ``options``, see :func:`demonstration_episode`) and
    append each episode as it finishes, counting it in ``summary``."""
    mode_counts: list[np.ndarray] = []
    done = writer.done()
    todo = [j for j in jobs if EpisodeKey(j.scenario, j.seed, j.episode) not in done]
    summary["skipped"] = len(jobs) - len(todo)
    bar = tqdm(total=len(jobs), initial=summary["skipped"], desc="collect", unit="ep", disable=not progress)

    def finished(record: dict[str, Any]) -> None:
        writer.append_episode(record["entry"], record["rows"])
        summary["episodes"] += 1
        summary["rows"] += len(record["rows"]["status"])
        mode_counts.append(np.sum(record["rows"]["mode_mask"], axis=1))
        summary["collided"] += int(record["entry"]["collided"])
        summary["plan_seconds"] += record["plan_seconds"]
        summary["sim_seconds"] += record["sim_seconds"]
        compile_notice(bar, "the expert planner", record.get("compile_seconds", 0.0))
        bar.update(1)
        bar.set_postfix_str(f"{record['entry']['scenario']} rows={summary['rows']} crashed={summary['collided']}")

    compile_ahead(bar, ["the expert planner"] if todo else [])
    try:
        execute(todo, options, demonstration_episode, finished, workers=workers)
    finally:
        bar.close()
    summary["modes_per_row"] = mode_distribution(np.concatenate(mode_counts) if mode_counts else [])

