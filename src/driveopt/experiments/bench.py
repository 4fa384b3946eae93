"""``driveopt bench``: scenarios x planners x seeds x episodes of the closed loop, resumable and parallel.

Jobs run through :mod:`driveopt.experiments.runner` (worker processes or Ray); the parent is the
only writer of ``episodes.jsonl`` and appends each record as soon as its episode finishes. A
rerun with the same output directory skips every finished job, so an interrupted sweep resumes
with no episode lost or repeated. The episode function (:func:`episode_record` by default: one
simulated episode, :mod:`driveopt.sim.rollout`) receives the job key and the options and derives
every random choice from them: same seeds, same results.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from driveopt.experiments.runner import EpisodeFn, execute
from driveopt.experiments.store import (
    JobKey,
    StoreError,
    append_record,
    key_of,
    load_records,
    pending,
    repair,
)
from driveopt.experiments.summary import (
    markdown_table,
    plot_summary,
    summarise,
    write_csv,
)
from driveopt.registry import get_planner
from driveopt.sim.rollout import run_episode


def episode_record(job: JobKey, options: dict[str, Any]) -> dict[str, Any]:
    """One simulated episode of ``job`` (scenario, planner, seed, episode) as a bench record.

    options (all optional): ``duration`` [s], ``samples`` (batch-size override, see
    ``OptimiserSpec.with_samples``), ``weights`` (learned prior checkpoint), ``config`` (planner-config
    overrides, nested sections).
    """
    samples = options.get("samples")
    spec = get_planner(job.planner).with_samples(int(samples) if samples else None).with_weights(options.get("weights"))
    spec = spec.with_overrides(**options.get("config", {}))
    return run_episode(job.scenario, spec, job.env_seed, duration=options.get("duration")).record()


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


def run_bench(
    spec: BenchSpec,
    out_dir: str | Path,
    *,
    workers: int | None = None,
    backend: str = "local",
    episode_fn: EpisodeFn = episode_record,
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
