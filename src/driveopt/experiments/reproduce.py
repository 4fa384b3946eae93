"""``driveopt reproduce p1|p2``: run each declared figure protocol through the bench store, then judge its claims.

Layout of the output folder ``DIR``::

    DIR/runs/<options>/            one driveopt bench folder per set of bench options (samples, replanning period,
                                   config, duration), shared by every figure: episodes.jsonl, spec.json, summaries
    DIR/report.md, DIR/report.json the claim rows (:mod:`driveopt.experiments.reproduce_report`)
    DIR/<figure>.png               collision rates and speeds of the figure's arms with their intervals

Every bench folder is resumable (:func:`driveopt.experiments.bench.run_bench`): a rerun with the same ``DIR`` skips the
episodes it holds, an arm (planner, scenario and options) that several figures compare runs its episodes once, and
Ctrl-C keeps the finished episodes. A ``DIR`` laid out by figure (``runs/<figure>/<options>``, earlier versions) is
merged into this layout first (:func:`merge_figure_folders`). Every protocol, name and option is checked before ``DIR`` is created or touched; one
reproduction at a time writes into ``DIR`` (it holds ``DIR/.lock``). The report covers the episodes of the
protocol as run (seeds and episodes per seed), read back from the folders and checked by the store.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from driveopt.errors import DriveoptError
from driveopt.experiments.bench import BenchSpec, episode_record, run_bench
from driveopt.experiments.protocols import (
    COLLISIONS,
    NO_WORSE,
    PLAN_TIME,
    QUESTIONS,
    SPEED,
    Arm,
    Claim,
    FigureProtocol,
    figures_of,
)
from driveopt.experiments.runner import EpisodeFn, check_backend
from driveopt.experiments.store import (
    RECORDS_FILE,
    SPEC_FILE,
    StoreError,
    append_record,
    clashing_weights,
    key_of,
    load_folder,
    merged_spec,
)
from driveopt.experiments.verdicts import ClaimResult, answer, evaluate
from driveopt.files import lock_output_folder, make_output_folder, write_json

RUNS = "runs"


class ReproduceError(DriveoptError):
    """A reproduction that cannot run: bad options, or a folder it cannot use."""


@dataclass(frozen=True)
class BenchRun:
    """The episodes one figure needs of one bench folder, ``DIR/runs/<folder>`` (:meth:`Arm.folder`), as a spec."""

    figure: str
    path: Path
    spec: BenchSpec


def bench_runs(figures: tuple[FigureProtocol, ...], out: Path) -> list[BenchRun]:
    """The bench runs ``figures`` need under ``out``, in order. Every figure's arms with the same options share one
    folder, so an arm two figures compare (e.g. P1 Figs. 7 and 8's ``bilevel``) runs its episodes once: a later run
    finds them recorded. Equal runs are listed once."""
    runs: list[BenchRun] = []
    for figure in figures:
        for folder, (scenarios, planners, options) in figure.runs().items():
            run = BenchRun(figure.figure, out / RUNS / folder,
                           BenchSpec(scenarios, planners, figure.seeds, figure.episodes, options))
            if not any(run.path == other.path and run.spec == other.spec for other in runs):
                runs.append(run)
    return runs


def merge_figure_folders(out: Path) -> list[str]:
    """Move the episodes of an output folder laid out by figure (``DIR/runs/<figure>/<folder>``, as ``driveopt
    reproduce`` wrote before figures shared their arms) into ``DIR/runs/<folder>``, where every figure reads them.
    An episode recorded in both keeps the copy already there (else the first figure's, in name order); the settings of
    both must agree (StoreError). Each moved folder is removed once its records are in place, so an interrupted merge
    resumes. Returns one line per folder moved."""
    moved = []
    runs = out / RUNS
    for old in sorted(runs.glob(f"*/*/{RECORDS_FILE}")):
        old_folder, new_folder = old.parent, runs / old.parent.name
        old_spec, old_records = load_folder(old_folder)
        new_spec, new_records = load_folder(new_folder) if new_folder.is_dir() else (None, [])
        if old_spec is not None:
            if new_spec is not None:
                if new_spec["options"] != old_spec["options"]:
                    raise StoreError(f"{old_folder} and {new_folder} hold episodes of other options; merge them by hand")
                clash = clashing_weights(old_spec, new_spec)
                if clash:
                    raise StoreError(f"{old_folder} and {new_folder} hold episodes of {', '.join(clash)} driven with other "
                                     "learned weights; merge them by hand")
            new_folder.mkdir(exist_ok=True)
            write_json(new_folder / SPEC_FILE, merged_spec(new_spec, old_spec))
            have = {key_of(r) for r in new_records}
            fresh = [r for r in old_records if key_of(r) not in have]
            for record in fresh:
                append_record(new_folder / RECORDS_FILE, record)
            there = len(old_records) - len(fresh)
            moved.append(f"{old_folder.relative_to(out)} -> {new_folder.relative_to(out)}: {len(fresh)} episodes moved"
                         + (f", {there} already there" if there else ""))
        shutil.rmtree(old_folder)
    for figure_folder in runs.glob("*/"):
        if not any(figure_folder.iterdir()):
            figure_folder.rmdir()
    return moved


def check(figures: tuple[FigureProtocol, ...], out: Path, backend: str, workers: int | None) -> list[BenchRun]:
    """Every bench run of ``figures`` checked (names, options, seeds, weights) before anything is written."""
    if workers is not None and (not isinstance(workers, int) or isinstance(workers, bool) or workers < 1):
        raise ReproduceError(f"workers must be an integer >= 1, got {workers!r}")
    check_backend(backend)
    if out.exists() and not out.is_dir():
        raise ReproduceError(f"the output folder {out} is an existing file; give a folder")
    runs = bench_runs(figures, out)
    for run in runs:
        run.spec.check()
    return runs


@dataclass(frozen=True)
class RunSlice:
    """Which episodes of the chosen figures to run: those of ``scenarios``, ``planners`` and arms planning with
    ``samples`` per sampler iteration (None: all), for a protocol too long to run at once. The report still covers
    every claim of the figures."""

    scenarios: tuple[str, ...] | None = None
    planners: tuple[str, ...] | None = None
    samples: tuple[int, ...] | None = None

    @property
    def everything(self) -> bool:
        return self.scenarios is None and self.planners is None and self.samples is None

    def cut(self, runs: list[BenchRun]) -> list[BenchRun]:
        """``runs`` cut to this slice's episodes; a run left with none is dropped. ReproduceError for a name or
        sample count that none of the runs has."""
        known = {"scenarios": {s for run in runs for s in run.spec.scenarios},
                 "planners": {p for run in runs for p in run.spec.planners},
                 "samples": {_samples(run) for run in runs} - {None}}
        for field, names in known.items():
            unknown = [str(name) for name in getattr(self, field) or () if name not in names]
            if unknown:
                theirs = ", ".join(map(str, sorted(names)))
                raise ReproduceError(f"the chosen figures have no {field} {', '.join(unknown)}; theirs: {theirs}")
        kept = []
        for run in runs:
            if self.samples is not None and _samples(run) not in self.samples:
                continue
            spec = run.spec
            cut = replace(spec, scenarios=tuple(s for s in spec.scenarios if self.scenarios is None or s in self.scenarios),
                          planners=tuple(p for p in spec.planners if self.planners is None or p in self.planners))
            if cut.scenarios and cut.planners:
                kept.append(replace(run, spec=cut))
        return kept


def _samples(run: BenchRun) -> int | None:
    """The samples per sampler iteration a bench folder's arms plan with (None: the planners' own)."""
    return run.spec.options.get("samples")


def reproduce(paper: str, out: str | Path, *, figures: list[str] | None = None, quick: bool = False,
              seeds: tuple[int, ...] | None = None, episodes: int | None = None, only: RunSlice = RunSlice(),
              report_only: bool = False, workers: int | None = None, backend: str = "local",
              episode_fn: EpisodeFn = episode_record, progress: bool = True,
              ) -> tuple[tuple[FigureProtocol, ...], list[ClaimResult]]:
    """Run what is missing of ``paper``'s protocols (``figures``: only those; ``quick``: their quick variants;
    ``seeds``/``episodes``: replace every figure's; ``only``: run only those episodes), then write
    ``DIR/report.md``, ``report.json`` and one PNG per figure. The report always covers every claim of the chosen
    figures, each over the episodes recorded for both its arms (a claim with none says "not run"); ``report_only``
    runs nothing and writes the report of what ``DIR`` holds. Returns the protocols and the claim rows. A
    DriveoptError before anything is written when an option, figure, planner, scenario or weights file is wrong;
    KeyboardInterrupt keeps the finished episodes."""
    chosen = figures_of(paper, figures, quick=quick, seeds=seeds, episodes=episodes)
    return chosen, run_figures(paper, chosen, out, only=only, report_only=report_only,
                               workers=workers, backend=backend, episode_fn=episode_fn, progress=progress)


def run_figures(paper: str, figures: tuple[FigureProtocol, ...], out: str | Path, *, only: RunSlice = RunSlice(),
                report_only: bool = False, workers: int | None = None, backend: str = "local",
                episode_fn: EpisodeFn = episode_record, progress: bool = True) -> list[ClaimResult]:
    """:func:`reproduce` for protocols given as objects (e.g. a protocol of one's own)."""
    from driveopt.experiments.reproduce_report import write_report

    out = Path(out)
    runs = only.cut(check(figures, out, backend, workers))
    if report_only:
        if not only.everything:
            raise ReproduceError("a report-only run runs nothing; scenarios, planners and samples choose what to run")
        if not (out / RUNS).is_dir():
            raise ReproduceError(f"{out} holds no runs to report on ({out / RUNS} is missing); run without report-only first")
        runs = []
    out = make_output_folder(out, ReproduceError, "the runs and the report")
    with lock_output_folder(out):
        for line in merge_figure_folders(out):
            print(f"driveopt reproduce: {line}", flush=True)
        if progress and runs:
            print(f"driveopt reproduce: {episodes_to_run(runs)} episodes to run in {len(runs)} bench runs", flush=True)
        for i, run in enumerate(runs, start=1):
            if progress:
                spec = run.spec
                print(f"[{i}/{len(runs)}] {run.figure}: {', '.join(spec.planners)} on {', '.join(spec.scenarios)} "
                      f"-> {run.path}", flush=True)
            run_bench(run.spec, run.path, workers=workers, backend=backend, episode_fn=episode_fn, progress=progress)
        results = judge(figures, out)
        write_report(paper, figures, results, out, code_versions(figures, out), answer_questions(paper, figures, out))
    return results


def episodes_to_run(runs: list[BenchRun]) -> int:
    """How many of the episodes ``runs`` ask for their folders do not hold yet."""
    missing = 0
    for run in runs:
        recorded = {key_of(r) for r in load_folder(run.path)[1]} if run.path.is_dir() else set()
        missing += sum(job not in recorded for job in run.spec.jobs())
    return missing


def records_by_arm(path: Path) -> dict[tuple[str, str], dict[tuple[int, int], dict[str, Any]]]:
    """``{(scenario, planner): {(seed, episode): record}}`` of one bench folder (empty when it has none)."""
    _, records = load_folder(path)
    out: dict[tuple[str, str], dict[tuple[int, int], dict[str, Any]]] = {}
    for r in records:
        out.setdefault((r["scenario"], r["planner"]), {})[(int(r["seed"]), int(r["episode"]))] = r
    return out


def _protocol_records(figure: FigureProtocol, out: Path, cache: dict[Path, Any], every_episode: bool = False):
    """``arm_records(arm, scenario)``: the records of ``figure``'s protocol as run (its seeds, episodes 0 .. episodes - 1;
    with ``every_episode``, every recorded episode of its seeds) of one arm on one scenario, keyed by (seed, episode);
    folders are read once per ``cache``."""

    def wanted(key: tuple[int, int]) -> bool:
        seed, episode = key
        return seed in figure.seeds and (every_episode or episode < figure.episodes)

    def arm_records(arm, scenario):
        path = out / RUNS / arm.folder(figure.duration)
        if path not in cache:
            cache[path] = records_by_arm(path)  # StoreError for a corrupted or foreign folder
        found = cache[path].get((scenario, arm.planner), {})
        return {k: r for k, r in found.items() if wanted(k)}

    return arm_records


def code_versions(figures: tuple[FigureProtocol, ...], out: Path) -> dict[str, dict[str, int]]:
    """``{figure: {code: episodes}}``: how many of the episodes each figure judges ran on which driveopt sources (the
    records' ``code`` digest; "unrecorded" for records without one)."""
    cache: dict[Path, Any] = {}
    versions: dict[str, dict[str, int]] = {}
    for figure in figures:
        arm_records, seen = _protocol_records(figure, out, cache), set()
        counts = versions.setdefault(figure.figure, {})
        for claim in figure.claims:
            for arm in (claim.arm, claim.baseline):
                for key, record in arm_records(arm, claim.scenario).items():
                    episode = (arm.folder(figure.duration), arm.planner, claim.scenario, key)
                    if episode not in seen:
                        seen.add(episode)
                        code = record.get("code", "unrecorded")
                        counts[code] = counts.get(code, 0) + 1
    return versions


def judge(figures: tuple[FigureProtocol, ...], out: Path) -> list[ClaimResult]:
    """Every claim of ``figures`` measured on the records under ``out``: only the episodes of the protocol as run
    (its seeds, episodes 0 .. episodes - 1)."""
    cache: dict[Path, Any] = {}
    results = []
    for figure in figures:
        arm_records = _protocol_records(figure, out, cache)
        for claim in figure.claims:
            results.append(evaluate(figure.figure, claim, arm_records(claim.arm, claim.scenario),
                                    arm_records(claim.baseline, claim.scenario), figure.seeds, figure.full_episodes,
                                    figure.reduced))
    return results


def answer_questions(paper: str, figures: tuple[FigureProtocol, ...], out: Path) -> list[ClaimResult]:
    """Every question of ``paper`` (:data:`~driveopt.experiments.protocols.QUESTIONS`) that ``figures`` have claims
    for, on each metric: the pairs of every claim tagged with it pooled (an episode of the same two arms on the same
    scenario once, whichever figures judge it; every recorded episode of the protocols' seeds, also beyond a
    figure's episode count: a question needs more pairs than one figure's protocol runs), each row's verdict the
    question's answer (:func:`~driveopt.experiments.verdicts.answer`). Rows with figure "pooled", scenario "every setting" and
    expectation "any change"."""
    cache: dict[Path, Any] = {}
    results = []
    for question in QUESTIONS.get(paper, ()):
        for metric in (COLLISIONS, SPEED, PLAN_TIME):
            tagged = [(f, c) for f in figures for c in f.claims if c.question == question.tag and c.metric == metric]
            if not tagged:
                continue
            arm_pool: dict[Any, dict[str, Any]] = {}
            baseline_pool: dict[Any, dict[str, Any]] = {}
            seeds: set[int] = set()
            for figure, claim in tagged:
                records = _protocol_records(figure, out, cache, every_episode=True)
                arm, baseline = records(claim.arm, claim.scenario), records(claim.baseline, claim.scenario)
                for key in arm.keys() & baseline.keys():
                    pooled = (claim.scenario, claim.arm.label, claim.baseline.label, *key)
                    arm_pool[pooled], baseline_pool[pooled] = arm[key], baseline[key]
                seeds.update(figure.seeds)
            first = tagged[0][1]
            every = "every setting"
            claim = Claim(every, Arm(first.arm.planner, first.arm.version, note=every),
                          Arm(first.baseline.planner, first.baseline.version, note=every), metric, NO_WORSE,
                          question.title, question=question.tag)
            result = evaluate("pooled", claim, arm_pool, baseline_pool, tuple(sorted(seeds)), question.min_pairs, False)
            results.append(replace(result, expect="any change", verdict=answer(result, question.min_pairs)))
    return results
