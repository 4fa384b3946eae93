"""``driveopt bench``: scenarios x planners x seeds x episodes of the closed loop, resumable and parallel.

Jobs run through :mod:`driveopt.experiments.runner` (worker processes or Ray); the parent is the
only writer of ``episodes.jsonl`` and appends each record as soon as its episode finishes. A
rerun with the same output directory skips every finished job, so an interrupted sweep resumes
with no episode lost or repeated. The episode function (:func:`episode_record` by default: one
simulated episode, :mod:`driveopt.experiments.rollout`) receives the job key and the options and derives
every random choice from them: same seeds, same results.

Everything a user can get wrong (names, options, backend) is checked before the output folder is
created or touched, and a folder is only refused when it holds episodes run with other options.
Ctrl-C or SIGTERM while episodes run stops at once (see :mod:`driveopt.experiments.runner`): the
finished episodes are kept and the summaries left as they were; summaries and ``spec.json`` are
replaced whole, never left half-written.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import jax
from tqdm import tqdm

from driveopt.checks import check_count, check_number
from driveopt.drivers.base import DriverSpec
from driveopt.errors import DriveoptError
from driveopt.experiments.rollout import run_episode
from driveopt.experiments.runner import EpisodeFn, check_backend, execute, usable_cpus
from driveopt.experiments.store import JobKey, StoreError, append_record, key_of, load_records, pending, repair
from driveopt.experiments.summary import markdown_table, plot_summary, summarise, write_csv
from driveopt.files import make_output_folder
from driveopt.registry import get_planner
from driveopt.sim.scenarios import resolve_scenario


class BenchOptionError(DriveoptError):
    """A bench option naming a file that does not exist (weights); ranges are ConfigErrors (driveopt.config)."""


def episode_record(job: JobKey, options: dict[str, Any]) -> dict[str, Any]:
    """One simulated episode of ``job`` (scenario, planner, seed, episode) as a bench record.

    options (all optional): ``duration`` [s], ``samples`` (batch-size override, see
    ``OptimiserSpec.with_samples``), ``weights`` (learned prior checkpoint), ``config`` (planner-config
    overrides, nested sections), ``replan_every`` (policy periods each plan is executed), ``scenario``
    (scenario-field overrides applied to every scenario, e.g. ``{"traffic_reverses": false}``).
    """
    spec = planner_spec(job.planner, options)
    scenario = resolve_scenario(job.scenario, overrides=options.get("scenario"))
    record = run_episode(scenario, spec, job.env_seed, duration=options.get("duration")).record()
    # where it planned, and on how many CPUs (the worker's share, see driveopt.experiments.runner): its plan_ms are theirs
    return {**record, "device": jax.default_backend(), "cpus": len(usable_cpus())}


def planner_spec(name: str, options: dict[str, Any]) -> DriverSpec:
    """The registered planner ``name`` with the bench options (samples, weights, config, replan_every) applied."""
    samples = options.get("samples")
    spec = get_planner(name).with_samples(int(samples) if samples else None).with_weights(options.get("weights"))
    return spec.with_overrides(**options.get("config", {})).with_replan_every(options.get("replan_every"))


@dataclass(frozen=True)
class BenchSpec:
    scenarios: tuple[str, ...]
    planners: tuple[str, ...]
    seeds: tuple[int, ...] = (42,)
    episodes: int = 50  # per (scenario, planner, seed)
    options: dict[str, Any] = field(default_factory=dict)  # passed to every episode (duration, samples, ...)
    episode_list: tuple[int, ...] = ()  # only these episode indices (each < episodes), e.g. an A/B on those that collided

    def jobs(self) -> list[JobKey]:
        return [
            JobKey(scenario, planner, seed, episode)
            for scenario in self.scenarios
            for seed in self.seeds
            for episode in (self.episode_list or range(self.episodes))
            for planner in self.planners
        ]

    def check(self) -> None:
        """Refuse, as a DriveoptError, what an episode would refuse: an episode list with an index twice or outside
        ``episodes``, an unknown scenario or planner, a duration that is not a finite number > 0, samples that are not
        an integer >= 1, a weights file that does not exist, config overrides the planner config rejects, weights a
        planner cannot use on a scenario's road (``DriverSpec.check``). Other options (those of a custom episode
        function) pass unchecked."""
        scenarios = [resolve_scenario(name, overrides=self.options.get("scenario")) for name in self.scenarios]
        check_options(self.options)
        outside = [e for e in self.episode_list if not 0 <= e < self.episodes]
        if outside or len(set(self.episode_list)) < len(self.episode_list):
            raise BenchOptionError(f"episode list {list(self.episode_list)}: each episode once, from 0 to {self.episodes - 1} "
                                   "(--episodes)")
        for name in self.planners:
            spec = planner_spec(name, self.options)
            for scenario in scenarios:
                spec.check(scenario)

    def weights_digests(self) -> dict[str, str]:
        """``{"planner/scenario": digest}`` of the learned weights each planner drives with on each scenario (given or
        shipped; see ``DriverSpec.weights_digest``); planners without learned weights are left out."""
        digests = {}
        for scenario_name in self.scenarios:
            scenario = resolve_scenario(scenario_name, overrides=self.options.get("scenario"))
            for name in self.planners:
                digest = planner_spec(name, self.options).weights_digest(scenario)
                if digest is not None:
                    digests[f"{name}/{scenario_name}"] = digest
        return digests


def check_options(options: dict[str, Any]) -> None:
    """BenchOptionError or ConfigError for a bench option out of range or a weights file that does not exist."""
    duration, samples, weights = options.get("duration"), options.get("samples"), options.get("weights")
    if duration is not None:
        check_number("duration", duration, 0.0, low_open=True, unit="s")
    if samples is not None:
        check_count("samples", samples)
    if weights is not None and not Path(weights).is_file():
        raise BenchOptionError(f"weights file {weights} does not exist")


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

    workers: parallel episodes (default: the CPUs this process may use); 1 runs in this process. backend: 'local' or 'ray'.
    Returns the summary rows over all records of the spec (old and new).
    """
    spec.check()
    check_backend(backend)
    out = Path(out_dir)
    make_output_folder(out, StoreError, "episodes.jsonl, spec.json and the summaries")
    store = out / "episodes.jsonl"
    done = load_records(store)
    _claim(out / "spec.json", spec, has_episodes=bool(done))
    repair(store)
    jobs = spec.jobs()
    todo = pending(jobs, done)
    workers = workers or len(usable_cpus())
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
    write_summaries(rows, out)
    return rows


def write_summaries(rows: list[dict[str, Any]], out: Path) -> None:
    """summary.csv, summary.md and (for any rows) summary.png of ``rows`` in the folder ``out``, each replaced whole."""
    _replace(out / "summary.csv", lambda path: write_csv(rows, path))
    _replace(out / "summary.md", lambda path: path.write_text(markdown_table(rows)))
    if rows:
        _replace(out / "summary.png", lambda path: plot_summary(rows, path))


def _claim(path: Path, spec: BenchSpec, *, has_episodes: bool) -> None:
    """Record ``spec`` and the digests of the learned weights it drives with in the output folder; StoreError when
    the folder holds episodes run with other options (samples, duration, weights, config) or, for a planner and
    scenario it recorded, other weights (e.g. shipped weights replaced since): resuming must not mix two settings
    in one table. A folder without episodes is free, whatever its spec.json says."""
    weights = spec.weights_digests()
    if has_episodes and path.exists():
        try:
            recorded = json.loads(path.read_text())
            options, recorded_weights = recorded["options"], recorded.get("weights", {})
        except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, AttributeError) as exc:
            raise StoreError(f"{path} is unreadable ({exc}); remove it or use another output folder") from None
        if options != json.loads(json.dumps(spec.options)):
            raise StoreError(f"{path.parent} holds episodes run with options {options}, not {spec.options}; "
                             "use another output folder")
        changed = sorted(key for key in set(recorded_weights) & set(weights) if recorded_weights[key] != weights[key])
        if changed:
            raise StoreError(f"{path.parent} holds episodes of {', '.join(changed)} driven with other learned weights "
                             f"(digest {recorded_weights[changed[0]]}, now {weights[changed[0]]}); use another output folder")
        weights = {**recorded_weights, **weights}
    _replace(path, lambda tmp: tmp.write_text(json.dumps({**asdict(spec), "weights": weights}, indent=1)))


def _replace(path: Path, write: Callable[[Path], Any]) -> None:
    """``write`` a temporary sibling of ``path`` (same suffix) and rename it over ``path``: an interrupted
    write leaves the previous file whole."""
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
