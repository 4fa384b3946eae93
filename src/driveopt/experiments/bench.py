"""``driveopt bench``: scenarios x planners x seeds x episodes of the closed loop, resumable and parallel.

Jobs run through :mod:`driveopt.experiments.runner` (worker processes or Ray); the parent is the
only writer of ``episodes.jsonl`` and appends each record as soon as its episode finishes. A
rerun with the same output directory skips every finished job, so an interrupted sweep resumes
with no episode lost or repeated. The episode function (:func:`episode_record` by default: one
simulated episode, :mod:`driveopt.experiments.rollout`) receives the job key and the options and derives
every random choice from them: same seeds, same results.

Everything a user can get wrong (names, options, seeds, backend) is checked before the output folder is
created or touched, and a folder is only refused when it holds episodes run with other options. One run at a
time writes into a folder (it holds ``.lock`` there; a second run is refused at once), every record names the
settings it ran with, and records are checked when read (:mod:`driveopt.experiments.store`), so a resume never
counts an episode twice or mixes two settings in one table. Ctrl-C or SIGTERM while episodes run stops at once
(see :mod:`driveopt.experiments.runner`): the finished episodes are kept and the summaries left as they were;
summaries and ``spec.json`` are replaced whole, never left half-written.
"""

from __future__ import annotations

import json
import math
import numbers
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from driveopt.checks import check_count, check_number
from driveopt.drivers.base import DriverSpec, check_weights_file
from driveopt.drivers.latency import parse_latency
from driveopt.errors import DriveoptError
from driveopt.experiments.arms import planner_spec, provenance
from driveopt.experiments.rollout import run_episode
from driveopt.experiments.runner import (
    EpisodeFn,
    check_backend,
    compile_ahead,
    compile_notice,
    execute,
    execute_cells,
    usable_cpus,
)
from driveopt.experiments.store import (
    RECORDS_FILE,
    SPEC_FILE,
    JobKey,
    StoreError,
    append_record,
    clashing,
    key_of,
    load_folder,
    merged_spec,
    pending,
    repair,
    seed_range_problem,
    settings_digest,
)
from driveopt.experiments.summary import markdown_table, plot_summary, summarise, write_csv
from driveopt.files import atomic_write, json_text, lock_output_folder, make_output_folder, write_json
from driveopt.sim.scenarios import resolve_scenario


class BenchOptionError(DriveoptError):
    """A bench option that cannot be used (a latency, an episode list, weights no planner takes); ranges are
    ConfigErrors (driveopt.config), weights paths that are not files WeightsErrors (driveopt.drivers.base)."""




def episode_record(job: JobKey, options: dict[str, Any]) -> dict[str, Any]:
    """One simulated episode of ``job`` (scenario, planner, seed, episode) as a bench record.

    options (all optional): ``duration`` [s], ``samples`` (batch-size override, see
    ``OptimiserSpec.with_samples``), ``weights`` (learned prior checkpoint), ``config`` (planner-config
    overrides, nested sections), ``replan_every`` (policy periods each plan is executed), ``latency`` (``"measured"`` or
    a compute time [ms]: plans take effect after their planning time, :mod:`driveopt.drivers.latency`; absent:
    the simulator waits for every plan; records then carry ``plan_periods``), ``scenario``
    (scenario-field overrides applied to every scenario, e.g. ``{"traffic_reverses": false}``).
    """
    spec = planner_spec(job.planner, options)
    scenario = resolve_scenario(job.scenario, overrides=options.get("scenario"))
    record = run_episode(scenario, spec, job.env_seed, duration=options.get("duration")).record()
    return {**record, **provenance()}


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
        """Refuse, as a DriveoptError, what an episode would refuse: a scenario, planner or seed given twice, a seed
        whose traffic seeds fall outside [0, MAX_ENV_SEED], an episode list with an index twice or outside
        ``episodes``, an unknown scenario or planner, a duration that is not a finite number > 0, samples that are not
        an integer >= 1, a latency that is not ``"measured"`` or a number of ms in [0, MAX_LATENCY_MS] (``"sync"`` is
    left out of the options: :func:`bench_latency`), a weights file that does not exist, weights none of the planners
        takes, config overrides the planner config rejects, weights a planner cannot use on a scenario's road
        (``DriverSpec.check``). Other options (those of a custom episode
        function) pass unchecked."""
        for name, values in (("scenarios", self.scenarios), ("planners", self.planners), ("seeds", self.seeds)):
            if len(set(values)) < len(values):
                raise BenchOptionError(f"{name} {list(values)}: give each once")
        check_count("episodes", self.episodes, 0)
        check_seeds(self.seeds, self.episodes)
        scenarios = [resolve_scenario(name, overrides=self.options.get("scenario")) for name in self.scenarios]
        check_options(self.options)
        outside = [e for e in self.episode_list if not 0 <= e < self.episodes]
        if outside or len(set(self.episode_list)) < len(self.episode_list):
            raise BenchOptionError(f"episode list {list(self.episode_list)}: each episode once, from 0 to {self.episodes - 1} "
                                   "(--episodes)")
        specs = [planner_spec(name, self.options) for name in self.planners]
        if self.options.get("weights") is not None and not any(spec.takes_weights for spec in specs):
            raise BenchOptionError(f"weights {self.options['weights']}: none of the planners {', '.join(self.planners)} "
                                   "takes weights (their priors are not learned); leave the weights out")
        for spec in specs:
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

    def config_digests(self) -> dict[str, str]:
        """``{planner: digest}`` of the configuration each planner plans with, the bench options applied
        (``DriverSpec.config_digest``); planners without one (``idm``, RL policies) are left out."""
        digests = {name: planner_spec(name, self.options).config_digest() for name in self.planners}
        return {name: digest for name, digest in digests.items() if digest is not None}


def check_seeds(seeds: tuple[int, ...], episodes: int) -> None:
    """BenchOptionError unless every seed is an integer whose episodes' traffic seeds (``seed * ENV_SEED_STRIDE +
    episode``) lie in [0, MAX_ENV_SEED]: beyond it JAX's 32-bit seed would repeat another episode's randomness."""
    for seed in seeds:
        if not (isinstance(seed, numbers.Integral) and not isinstance(seed, bool)):
            raise BenchOptionError(f"seed {seed!r} is not an integer")
        problem = seed_range_problem(seed, episodes)
        if problem:
            raise BenchOptionError(problem)


def check_options(options: dict[str, Any]) -> None:
    """BenchOptionError or ConfigError for a bench option out of range, WeightsError (driveopt.drivers.base) for a
    weights path that is not a regular file, as everywhere weights are given."""
    duration, samples, weights = options.get("duration"), options.get("samples"), options.get("weights")
    if duration is not None:
        check_number("duration", duration, 0.0, low_open=True, unit="s")
    if samples is not None:
        check_count("samples", samples)
    if "latency" in options and bench_latency(options["latency"]) != options["latency"]:
        raise BenchOptionError(f"latency {options['latency']!r}: give \"measured\" or a number of ms, or leave the option "
                               "out for synchronous planning")
    check_weights_file(weights)


def bench_latency(latency: Any) -> str | float | None:
    """The bench option value of ``latency`` (``"sync"``, ``"measured"``, a compute time [ms]; see
    :func:`driveopt.drivers.latency.parse_latency`): None for synchronous planning, so that a synchronous folder's
    settings are those of a folder made without the option. LatencyError for an unknown or out-of-range value."""
    return parse_latency(latency).option


def run_bench(
    spec: BenchSpec,
    out_dir: str | Path,
    *,
    workers: int | None = None,
    backend: str = "local",
    episode_fn: EpisodeFn = episode_record,
    progress: bool = True,
    lockstep: int | None = None,
) -> list[dict[str, Any]]:
    """Run the missing jobs of ``spec``, then write summary.csv, summary.md, summary.json and summary.png.

    workers: parallel episodes (default: the CPUs this process may use); 1 runs in this process. backend: 'local' or 'ray'.
    lockstep: episodes of one arm stepped together, one planning call for all per policy step
    (:mod:`driveopt.experiments.lockstep`): in this process (``workers`` 1, the default with it), as cells of jobs in
    ``workers`` local processes, or as Ray tasks of cells; only for optimiser planners with synchronous latency and
    the default ``episode_fn``. None: one episode at a time.
    Returns the summary rows over every record of the folder (this spec's, old and new, then those of other runs that
    share the folder). OutputInUseError (driveopt.files) at once when another run holds the folder.
    """
    spec.check()
    check_backend(backend)
    if lockstep is not None:
        check_lockstep_run(spec, lockstep, episode_fn)
        workers = workers or 1
    out = make_output_folder(out_dir, StoreError, "episodes.jsonl, spec.json and the summaries")
    with lock_output_folder(out):
        return _run_locked(spec, out, workers or len(usable_cpus()), backend, episode_fn, progress, lockstep)


def check_lockstep_run(spec: BenchSpec, lockstep: int, episode_fn: EpisodeFn) -> None:
    """BenchOptionError or LockstepError unless ``spec`` can run ``lockstep`` episodes per planning call: every planner
    an optimiser with synchronous latency, the simulated episodes (not a custom ``episode_fn``)."""
    from driveopt.experiments.lockstep import check_lockstep

    if episode_fn is not episode_record:
        raise BenchOptionError("lock-step runs the simulated episodes only, not a custom episode function")
    for name in spec.planners:
        check_lockstep(planner_spec(name, spec.options), lockstep)


def _run_locked(spec: BenchSpec, out: Path, workers: int, backend: str, episode_fn: EpisodeFn,
                progress: bool, lockstep: int | None = None) -> list[dict[str, Any]]:
    """:func:`run_bench` in the folder ``out``, which this process holds."""
    store = out / RECORDS_FILE
    recorded, done = load_folder(out)
    settings = _claim(out / SPEC_FILE, spec, recorded)
    repair(store)
    jobs = spec.jobs()
    todo = pending(jobs, done)
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), desc="bench", unit="ep", disable=not progress)

    def finished(record: dict) -> None:
        append_record(store, {**record, "settings": settings[(record["scenario"], record["planner"])]})
        compile_notice(bar, record["planner"], record.get("compile_seconds", 0.0))
        bar.update(1)
        bar.set_postfix_str(f"{record['scenario']}/{record['planner']} crashed={record['collided']}")

    compile_ahead(bar, sorted({job.planner for job in todo}))
    try:
        if lockstep is None:
            execute(todo, spec.options, episode_fn, finished, workers=workers, backend=backend)
        else:
            _run_lockstep(todo, spec.options, finished, lockstep, backend, workers)
    finally:
        bar.close()

    # The summaries cover every episode of the folder, which other runs may share: this run's in the spec's order
    # (not completion order), then the others as recorded.
    order = {job: i for i, job in enumerate(jobs)}
    records = sorted(load_folder(out)[1], key=lambda r: order.get(key_of(r), len(order)))
    rows = summarise(records)
    write_summaries(rows, out)
    return rows


def _run_lockstep(todo: list[JobKey], options: dict[str, Any], finished: Any, slots: int, backend: str,
                  workers: int) -> None:
    """The jobs ``todo`` in lock-step, ``slots`` episodes per planning call: each arm whole in this process, cut into
    about as many cells as local ``workers`` (so that each has a share), or into cells of
    :data:`driveopt.experiments.lockstep.CELL_ROUNDS` x ``slots`` jobs, one Ray task each."""
    from driveopt.experiments.lockstep import run_lockstep

    execute_cells(lockstep_cells(todo, slots, backend, workers), options, run_lockstep, finished, args=(slots,),
                  backend=backend, workers=workers)


def lockstep_cells(todo: list[JobKey], slots: int, backend: str, workers: int) -> list[list[JobKey]]:
    """How :func:`_run_lockstep` cuts ``todo`` (see there)."""
    from driveopt.experiments.lockstep import cells

    if backend == "ray":
        return cells(todo, slots)
    return cells(todo, slots, rounds=max(math.ceil(len(todo) / (slots * workers)), 1))


def write_summaries(rows: list[dict[str, Any]], out: Path) -> None:
    """summary.csv, summary.md, summary.json (strict JSON: a missing number is null) and (for any rows) summary.png
    of ``rows`` in the folder ``out``, each replaced whole."""
    write_csv(rows, out / "summary.csv")
    atomic_write(out / "summary.md", markdown_table(rows).encode())
    write_json(out / "summary.json", rows)
    if rows:
        plot_summary(rows, out / "summary.png")


def _claim(path: Path, spec: BenchSpec, recorded: dict[str, Any] | None) -> dict[tuple[str, str], str]:
    """Add ``spec`` and the digests of the learned weights and configurations it drives with to the folder's spec.json
    (:func:`driveopt.experiments.store.merged_spec`); StoreError when the folder holds episodes (``recorded``: their
    spec.json) run with other options (samples, duration, weights, config), or, for a planner (and scenario) it
    recorded, other weights (e.g. shipped weights replaced since) or another configuration (a default changed since):
    resuming must not mix two settings in one table. A folder without episodes is free, whatever its spec.json says.

    Returns the settings digest (:func:`driveopt.experiments.store.settings_digest`) of each (scenario, planner)."""
    run = json.loads(json_text({**asdict(spec), "weights": spec.weights_digests(), "configs": spec.config_digests()}))
    options = run["options"]
    if recorded is not None:
        if recorded["options"] != options:
            raise StoreError(f"{path.parent} holds episodes run with options {recorded['options']}, not {spec.options}; "
                             "use another output folder")
        for name, what in (("weights", "with other learned weights (e.g. shipped weights replaced since)"),
                           ("configs", "with another planner configuration (its defaults changed since)")):
            changed = clashing(recorded, run, name)
            if changed:
                raise StoreError(f"{path.parent} holds episodes of {', '.join(changed)} driven {what}: digest "
                                 f"{recorded[name][changed[0]]}, now {run[name][changed[0]]}; use another output folder")
    folder = merged_spec(recorded, run)
    write_json(path, folder)
    return {(scenario, planner): settings_digest(options, folder["weights"].get(f"{planner}/{scenario}"))
            for scenario in spec.scenarios for planner in spec.planners}
