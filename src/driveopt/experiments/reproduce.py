"""``driveopt reproduce p1|p2``: run each declared figure protocol through the bench store, then judge its claims.

Layout of the output folder ``DIR``::

    DIR/runs/<figure>/<options>/   one driveopt bench folder per set of bench options (samples, replanning period,
                                   config, duration): episodes.jsonl, spec.json, summaries
    DIR/report.md, DIR/report.json the claim rows (:mod:`driveopt.experiments.reproduce_report`)
    DIR/<figure>.png               collision rates and speeds of the figure's arms with their intervals

Every bench folder is resumable (:func:`driveopt.experiments.bench.run_bench`): a rerun with the same ``DIR`` skips the
episodes it holds, a figure's records are reused by any later run that asks for the same options, and Ctrl-C keeps
the finished episodes. Every protocol, name and option is checked before ``DIR`` is created or touched; one
reproduction at a time writes into ``DIR`` (it holds ``DIR/.lock``). The report covers the episodes of the
protocol as run (seeds and episodes per seed), read back from the folders and checked by the store.
"""

from __future__ import annotations

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
from driveopt.experiments.store import load_folder
from driveopt.experiments.verdicts import ClaimResult, answer, evaluate
from driveopt.files import lock_output_folder, make_output_folder

RUNS = "runs"


class ReproduceError(DriveoptError):
    """A reproduction that cannot run: bad options, or a folder it cannot use."""


@dataclass(frozen=True)
class BenchRun:
    """One bench folder of a figure: ``DIR/runs/<runs_folder>/<folder>`` with its spec."""

    figure: str
    path: Path
    spec: BenchSpec


def bench_runs(figures: tuple[FigureProtocol, ...], out: Path) -> list[BenchRun]:
    """The bench folders ``figures`` need under ``out``, in order; a folder two figures share is listed once."""
    runs: dict[Path, BenchRun] = {}
    for figure in figures:
        for folder, (scenarios, planners, options) in figure.runs().items():
            path = out / RUNS / figure.runs_folder / folder
            spec = BenchSpec(scenarios, planners, figure.seeds, figure.episodes, options)
            if path in runs and runs[path].spec != spec:
                raise ReproduceError(f"figures ask for two different runs in {path}; give them the same seeds and episodes")
            runs.setdefault(path, BenchRun(figure.figure, path, spec))
    return list(runs.values())


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
        for i, run in enumerate(runs, start=1):
            if progress:
                spec = run.spec
                print(f"[{i}/{len(runs)}] {run.figure}: {', '.join(spec.planners)} on {', '.join(spec.scenarios)} "
                      f"-> {run.path}", flush=True)
            run_bench(run.spec, run.path, workers=workers, backend=backend, episode_fn=episode_fn, progress=progress)
        results = judge(figures, out)
        write_report(paper, figures, results, out, code_versions(figures, out), answer_questions(paper, figures, out))
    return results


def records_by_arm(path: Path) -> dict[tuple[str, str], dict[tuple[int, int], dict[str, Any]]]:
    """``{(scenario, planner): {(seed, episode): record}}`` of one bench folder (empty when it has none)."""
    _, records = load_folder(path)
    out: dict[tuple[str, str], dict[tuple[int, int], dict[str, Any]]] = {}
    for r in records:
        out.setdefault((r["scenario"], r["planner"]), {})[(int(r["seed"]), int(r["episode"]))] = r
    return out


def _protocol_records(figure: FigureProtocol, out: Path, cache: dict[Path, Any]):
    """``arm_records(arm, scenario)``: the records of ``figure``'s protocol as run (its seeds, episodes 0 .. episodes - 1)
    of one arm on one scenario, keyed by (seed, episode); folders are read once per ``cache``."""
    wanted = {(s, e) for s in figure.seeds for e in range(figure.episodes)}

    def arm_records(arm, scenario):
        path = out / RUNS / figure.runs_folder / arm.folder(figure.duration)
        if path not in cache:
            cache[path] = records_by_arm(path)  # StoreError for a corrupted or foreign folder
        found = cache[path].get((scenario, arm.planner), {})
        return {k: r for k, r in found.items() if k in wanted}

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
    scenario once, whichever figures judge it; the protocols' episodes as run), each row's verdict the question's
    answer (:func:`~driveopt.experiments.verdicts.answer`). Rows with figure "pooled", scenario "every setting" and
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
                records = _protocol_records(figure, out, cache)
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
