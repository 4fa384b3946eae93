"""``driveopt bench``: scenarios x planners x seeds x episodes, resumable and parallel.

Jobs run in worker processes (local, spawn start method) or on a Ray cluster; the parent is the
only writer of ``episodes.jsonl`` and appends each record as soon as its episode finishes. A
rerun with the same output directory skips every finished job, so an interrupted sweep resumes
with no episode lost or repeated. The episode function receives the job key and the options and
must derive every random choice from them: same seeds, same results.
"""

from __future__ import annotations

import concurrent.futures as cf
import importlib
import json
import multiprocessing
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

from tqdm import tqdm

from driveopt.bench.store import JobKey, StoreError, append_record, key_of, load_records, pending, repair

from driveopt.bench.summary import markdown_table, plot_summary, summarise, write_csv

EpisodeFn = Callable[[JobKey, dict], dict]
DEFAULT_EPISODE_FN = "driveopt.sim.mpc:episode_record"


@dataclass(frozen=True)
class BenchSpec:
    scenarios: tuple[str, ...]
    planners: tuple[str, ...]
    seeds: tuple[int, ...] = (42,)
    episodes: int = 50  # per (scenario, planner, seed)
    options: dict[str, Any] = field(default_factory=dict)  # passed to every episode (duration, samples, ...)

    def jobs(self) -> list[JobKey]:
        return [
            JobKey(scenario, planner, seed, episode)
            for scenario in self.scenarios
            for seed in self.seeds
            for episode in range(self.episodes)
            for planner in self.planners
        ]


def resolve(fn: str | EpisodeFn) -> EpisodeFn:
    """A callable, or 'module:function'."""
    if callable(fn):
        return fn
    module, _, name = fn.partition(":")
    return getattr(importlib.import_module(module), name)


def _call(fn: str | EpisodeFn, job: JobKey, options: dict) -> dict:
    record = resolve(fn)(job, options)
    return {**record, **job._asdict()}


def run_bench(
    spec: BenchSpec,
    out_dir: str | Path,
    *,
    workers: int | None = None,
    backend: str = "local",
    episode_fn: str | EpisodeFn = DEFAULT_EPISODE_FN,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Run the missing jobs of ``spec``, then write summary.csv, summary.md and summary.png.

    workers: parallel episodes (default: CPU count); 1 runs in this process. backend: 'local' or 'ray'.
    Returns the summary rows over all records of the spec (old and new).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    _claim(out / "spec.json", spec)
    store = out / "episodes.jsonl"
    repair(store)
    jobs = spec.jobs()
    todo = pending(jobs, load_records(store))
    workers = workers or os.cpu_count() or 1
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), desc="bench", unit="ep", disable=not progress)

    def finished(record: dict) -> None:
        append_record(store, record)
        bar.update(1)
        bar.set_postfix_str(f"{record['scenario']}/{record['planner']} crashed={record['collided']}")

    try:
        execute(todo, spec.options, episode_fn, finished, workers=workers, backend=backend)
    finally:
        bar.close()

    order = {job: i for i, job in enumerate(jobs)}  # summaries follow the spec, not completion order
    records = sorted((r for r in load_records(store) if key_of(r) in order), key=lambda r: order[key_of(r)])
    rows = summarise(records)
    write_csv(rows, out / "summary.csv")
    (out / "summary.md").write_text(markdown_table(rows))
    if rows:
        plot_summary(rows, out / "summary.png")
    return rows


def _claim(path: Path, spec: BenchSpec) -> None:
    """Record ``spec`` in the output folder; StoreError when the folder holds episodes run with other
    options (samples, duration, weights, config): resuming must not mix two settings in one table."""
    if path.exists():
        try:
            options = json.loads(path.read_text())["options"]
        except (json.JSONDecodeError, KeyError, TypeError) as exc:
            raise StoreError(f"{path} is unreadable ({exc}); remove it or use another output folder") from None
        if options != json.loads(json.dumps(spec.options)):
            raise StoreError(f"{path.parent} holds episodes run with options {options}, not {spec.options}; "
                             "use another output folder")
    path.write_text(json.dumps(asdict(spec), indent=1))


def execute(
    todo: Sequence[JobKey],
    options: dict,
    episode_fn: str | EpisodeFn,
    finished: Callable[[dict], None],
    *,
    workers: int = 1,
    backend: str = "local",
) -> None:
    """Run ``episode_fn(job, options)`` for every job and hand each record to ``finished`` as it comes.

    ``finished`` runs in this process (the single writer). workers: local processes (spawn);
    1 runs in this process. backend: 'local' or 'ray'.
    """
    if backend == "ray":
        _run_ray(todo, options, episode_fn, finished)
    elif backend != "local":
        raise ValueError(f"unknown backend '{backend}'; valid: local, ray")
    elif workers == 1:
        for job in todo:
            finished(_call(episode_fn, job, options))
    else:
        ctx = multiprocessing.get_context("spawn")
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            futures = [pool.submit(_call, episode_fn, job, options) for job in todo]
            try:
                for future in cf.as_completed(futures):
                    finished(future.result())
            except BaseException:
                for future in futures:
                    future.cancel()
                raise


def _run_ray(todo: Sequence[JobKey], options: dict, episode_fn: str | EpisodeFn, finished: Callable[[dict], None]) -> None:
    try:
        import ray
    except ImportError:
        raise RuntimeError("the ray backend needs Ray: pip install 'ray[default]' (or use --backend local)") from None
    if not ray.is_initialized():
        ray.init(address=os.environ.get("RAY_ADDRESS"), ignore_reinit_error=True)
    remote = ray.remote(_call)
    refs = [remote.remote(episode_fn, job, options) for job in todo]
    while refs:
        done, refs = ray.wait(refs, num_returns=1)
        finished(ray.get(done[0]))
