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

``claim``: run only one claim's two arms (its id, :func:`driveopt.experiments.protocols.claim_ids`), only the episodes
missing for its pairs, through the same bench folders; the report still covers every claim. :func:`plan` reads the
records alone and says, for each undecided claim, the pairs a decision needs and what they cost.
"""

from __future__ import annotations

import math
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

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
    DIGESTS,
    RECORDS_FILE,
    SPEC_FILE,
    StoreError,
    append_record,
    clashing,
    key_of,
    load_folder,
    merged_spec,
)
from driveopt.experiments.effects import NOT_DECIDABLE
from driveopt.experiments.error_control import obrien_fleming_levels
from driveopt.experiments.verdicts import (
    ALPHA,
    UNDECIDED,
    ClaimResult,
    answer,
    control_figure,
    evaluate,
    information,
    pairs_to_decide,
)
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
                for name in DIGESTS:
                    clash = clashing(old_spec, new_spec, name)
                    if clash:
                        raise StoreError(f"{old_folder} and {new_folder} hold episodes of {', '.join(clash)} driven with "
                                         f"other {'learned weights' if name == 'weights' else 'configurations'}; merge "
                                         "them by hand")
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
              episode_fn: EpisodeFn = episode_record, progress: bool = True, claim: str | None = None,
              ) -> tuple[tuple[FigureProtocol, ...], list[ClaimResult]]:
    """Run what is missing of ``paper``'s protocols (``figures``: only those; ``quick``: their quick variants;
    ``seeds``/``episodes``: replace every figure's; ``only``: run only those episodes), then write
    ``DIR/report.md``, ``report.json`` and one PNG per figure. The report always covers every claim of the chosen
    figures, each over the episodes recorded for both its arms (a claim with none says "not run"); ``report_only``
    runs nothing and writes the report of what ``DIR`` holds; ``claim``: run only that claim's arms (its id). Returns
    the protocols and the claim rows. A
    DriveoptError before anything is written when an option, figure, planner, scenario or weights file is wrong;
    KeyboardInterrupt keeps the finished episodes."""
    chosen = figures_of(paper, figures, quick=quick, seeds=seeds, episodes=episodes)
    return chosen, run_figures(paper, chosen, out, only=only, report_only=report_only, workers=workers,
                               backend=backend, episode_fn=episode_fn, progress=progress, claim=claim)


def run_figures(paper: str, figures: tuple[FigureProtocol, ...], out: str | Path, *, only: RunSlice = RunSlice(),
                report_only: bool = False, workers: int | None = None, backend: str = "local",
                episode_fn: EpisodeFn = episode_record, progress: bool = True,
                claim: str | None = None) -> list[ClaimResult]:
    """:func:`reproduce` for protocols given as objects (e.g. a protocol of one's own)."""
    from driveopt.experiments.reproduce_report import write_report

    out = Path(out)
    if claim is not None:
        if report_only or not only.everything:
            raise ReproduceError("a claim names what to run: give it without report-only, scenarios, planners or samples")
        runs = check((claim_protocol(figures, claim),), out, backend, workers)
    else:
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
            print(f"driveopt reproduce: {episodes_to_run(runs)} episodes to run in {len(runs)} bench runs "
                  f"({len({run.path for run in runs})} bench folders)", flush=True)
        for i, run in enumerate(runs, start=1):
            if progress:
                spec = run.spec
                print(f"[{i}/{len(runs)}] {run.figure}: {', '.join(spec.planners)} on {', '.join(spec.scenarios)} "
                      f"-> {run.path}", flush=True)
            run_bench(run.spec, run.path, workers=workers, backend=backend, episode_fn=episode_fn, progress=progress)
        results = judge(figures, out)
        write_report(paper, figures, results, out, code_versions(figures, out), answer_questions(paper, figures, out))
    return results


def find_claim(figures: tuple[FigureProtocol, ...], claim_id: str) -> tuple[FigureProtocol, Claim]:
    """The figure and claim of ``claim_id`` among ``figures``; ReproduceError naming where the ids are listed."""
    for figure in figures:
        for claim, this in zip(figure.claims, figure.claim_ids()):
            if this == claim_id:
                return figure, claim
    raise ReproduceError(f"no claim {claim_id!r} in the chosen figures; `driveopt reproduce {figures[0].paper if figures else 'p1'} "
                         "--plan --out DIR` lists the undecided claims' ids")


def claim_protocol(figures: tuple[FigureProtocol, ...], claim_id: str) -> FigureProtocol:
    """The protocol of one claim: its figure with that claim alone (its runs are the claim's two arms, in the bench
    folders the whole figure uses, so only their missing episodes run)."""
    figure, claim = find_claim(figures, claim_id)
    return replace(figure, claims=(claim,), primary="")


def episodes_to_run(runs: list[BenchRun]) -> int:
    """How many distinct episodes ``runs`` ask for that their folders do not hold yet (runs sharing a folder share its
    episodes: one that two runs ask for runs once)."""
    missing: set[tuple[Path, Any]] = set()
    for run in runs:
        recorded = {key_of(r) for r in load_folder(run.path)[1]} if run.path.is_dir() else set()
        missing.update((run.path, job) for job in run.spec.jobs() if job not in recorded)
    return len(missing)


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


def test_key(figure: FigureProtocol, claim: Claim) -> str:
    """The same string for claims that are one test: the same arms (planner and bench folder), scenario, metric,
    expectation and paper's effect, whichever figures declare them (P2 Fig. 8a's 100-iteration point is Fig. 7's
    density-3 learned against plain filter)."""
    arm, base = claim.arm, claim.baseline
    return (f"{claim.scenario}|{arm.planner}@{arm.folder(figure.duration)}|{base.planner}@{base.folder(figure.duration)}|"
            f"{claim.metric}|{claim.expect}|{claim.effect.ratio}|{claim.effect.arm_level}|{claim.effect.baseline_level}")


PROVENANCE_FIELDS = ("code", "jax", "numpy", "cpu_model", "device")  # what a record says about where it ran


def provenance(folder: str, planner: str, records: list[dict[str, Any]]) -> dict[str, Any]:
    """Where one arm's records of a claim come from: the bench folder (under ``DIR/runs``), the planner, how many
    episodes, and per distinct (code digest, jax, numpy, processor, device) the episodes that name it (a field a
    record lacks is null)."""
    groups: dict[tuple, int] = {}
    for record in records:
        key = tuple(record.get(name) for name in PROVENANCE_FIELDS)
        groups[key] = groups.get(key, 0) + 1
    return {"folder": f"{RUNS}/{folder}", "planner": planner, "episodes": len(records),
            "sources": [{**dict(zip(PROVENANCE_FIELDS, key)), "episodes": n}
                        for key, n in sorted(groups.items(), key=lambda item: -item[1])]}


def judge(figures: tuple[FigureProtocol, ...], out: Path) -> list[ClaimResult]:
    """Every claim of ``figures`` measured on the records under ``out``: only the episodes of the protocol as run
    (its seeds, episodes 0 .. episodes - 1), each figure's claims at the levels of its looks with Holm's adjustment
    (:func:`~driveopt.experiments.verdicts.control_figure`)."""
    cache: dict[Path, Any] = {}
    results = []
    for figure in figures:
        arm_records = _protocol_records(figure, out, cache)
        measured = []
        for claim, claim_id in zip(figure.claims, figure.claim_ids()):
            arm, baseline = arm_records(claim.arm, claim.scenario), arm_records(claim.baseline, claim.scenario)
            keys = sorted(arm.keys() & baseline.keys())
            result = evaluate(figure.figure, claim, arm, baseline, figure.seeds, figure.full_episodes, figure.reduced,
                              claim_id=claim_id, primary=claim_id == figure.primary)
            used = {side: provenance(a.folder(figure.duration), a.planner,
                                     [records[k] for k in keys] if keys else list(records.values()))
                    for side, a, records in (("arm", claim.arm, arm), ("baseline", claim.baseline, baseline))}
            measured.append(replace(result, test_key=test_key(figure, claim), records=used))
        results += control_figure(measured, figure.look_pairs)
    return results


@dataclass(frozen=True)
class PlanRow:
    """One undecided claim as :func:`plan` costs it. ``paper_pairs``/``measured_pairs``: total pairs at which its rule
    decides with 80% power at the figure's final level, at the paper's stated size (NaN: it states none) and at the
    measured rates (inf: they never decide it); ``seconds_per_pair``: the two arms' mean wall seconds per episode
    (planning plus simulation, one worker) from the recorded episodes; ``target_pairs``: the first look beyond the
    pairs held that holds the pairs needed (at the paper's size where stated, else at the measured rates); ``cost``:
    the seconds the pairs up to it take (inf when the rates never decide it or the protocol's pairs are spent).
    ``pairs``: those held (for plan time, those compared on one processor)."""

    claim_id: str
    verdict: str
    pairs: int
    full_pairs: int
    paper_pairs: float
    measured_pairs: float
    seconds_per_pair: float
    target_pairs: float
    cost: float


def _planner_seconds(out: Path, cache: dict[Path, Any], folder: str, planner: str) -> float:
    """Mean wall seconds per episode of ``planner`` in ``DIR/runs/folder`` over every scenario (NaN: none recorded)."""
    path = out / RUNS / folder
    if path not in cache:
        cache[path] = records_by_arm(path) if path.is_dir() else {}
    seconds = [float(r["plan_seconds"]) + float(r["sim_seconds"])
               for (_, name), records in cache[path].items() if name == planner for r in records.values()]
    return sum(seconds) / len(seconds) if seconds else math.nan


def plan(paper: str, out: str | Path, *, figures: list[str] | None = None, seeds: tuple[int, ...] | None = None,
         episodes: int | None = None) -> tuple[list[PlanRow], int]:
    """The undecided claims of ``paper``'s figures on the records under ``out`` (nothing runs), cheapest decision
    first (a claim whose cost cannot be estimated last), and how many claims the figures have. An arm without a
    record of the claim's scenario is costed by its records on the figure's other scenarios; a claim without a pair
    targets the figure's first look (its cost unknown when neither arm has run anywhere)."""
    out = Path(out)
    chosen = figures_of(paper, figures, seeds=seeds, episodes=episodes)
    if not (out / RUNS).is_dir():
        raise ReproduceError(f"{out} holds no runs to plan from ({out / RUNS} is missing)")
    results = judge(chosen, out)
    by_id = {(f.figure, i): (f, c) for f in chosen for c, i in zip(f.claims, f.claim_ids())}
    cache: dict[Path, Any] = {}
    rows = []
    for r in results:
        if r.verdict not in UNDECIDED:
            continue
        figure, claim = by_id[(r.figure, r.claim_id)]
        final = obrien_fleming_levels(figure.look_pairs, ALPHA)[-1]
        paper_pairs, measured_pairs = pairs_to_decide(r, final)
        seconds = 0.0
        for arm, stats_ in ((claim.arm, r.arm), (claim.baseline, r.baseline)):
            each = stats_.episode_seconds
            if not math.isfinite(each):
                each = _planner_seconds(out, cache, arm.folder(figure.duration), arm.planner)
            seconds += each
        info = information(r)  # plan time: the pairs compared on one processor
        target = paper_pairs if math.isfinite(paper_pairs) else measured_pairs
        if r.pairs == 0:  # nothing to estimate a rate or a cost from: the first look measures both
            target = figure.look_pairs[0]
        if info >= figure.look_pairs[-1] or not math.isfinite(target) or r.verdict == NOT_DECIDABLE:
            target, cost = math.inf, math.inf  # the protocol's pairs are spent, or the rates never decide it
        else:  # decisions fall at looks: the first look beyond the pairs held with the pairs needed (at most the last)
            target = next(n for n in figure.look_pairs if n >= min(max(target, info + 1), figure.look_pairs[-1]))
            cost = seconds * (target - info)
        rows.append(PlanRow(r.claim_id, r.verdict + (" (interim)" if r.interim else ""), info, r.full_pairs,
                            paper_pairs, measured_pairs, seconds, target, cost))
    rows.sort(key=lambda row: (not math.isfinite(row.cost), row.cost if math.isfinite(row.cost) else 0.0, row.claim_id))
    return rows, len(results)


def _in_slice(claim: Claim, only: RunSlice) -> bool:
    """Whether both arms of ``claim`` lie in ``only`` (its scenario, planners and samples)."""
    arms = (claim.arm, claim.baseline)
    return ((only.scenarios is None or claim.scenario in only.scenarios)
            and (only.planners is None or all(arm.planner in only.planners for arm in arms))
            and (only.samples is None or all(arm.samples in only.samples for arm in arms)))


def decide(paper: str, out: str | Path, *, figures: list[str] | None = None, only: RunSlice = RunSlice(),
           hours: float = math.inf, workers: int | None = None, backend: str = "local",
           episode_fn: EpisodeFn = episode_record, progress: bool = True,
           clock: Callable[[], float] = time.monotonic) -> list[str]:
    """Buy decisions at least cost: while ``hours`` last, run the cheapest undecided claim of :func:`plan` (among
    those whose arms lie in ``only``; claims no arm has run, whose cost is unknown, after the others) up to its next
    look, and plan again, so each claim stops at the look where its
    sequential boundary decides it. A claim whose pairs a run did not raise (its arms' episodes are all recorded) is
    not chosen again. Ends with the report of the full protocols over everything recorded; returns the ids run, in
    order. A claim started before the deadline runs to its look."""
    out = Path(out)
    chosen = figures_of(paper, figures)
    deadline = clock() + hours * 3600.0
    ran: list[str] = []
    stuck: set[str] = set()
    while clock() < deadline:
        rows, _ = plan(paper, out, figures=figures)
        candidates = [row for row in rows if (math.isfinite(row.cost) or (row.pairs == 0 and math.isfinite(row.target_pairs)))
                      and row.claim_id not in stuck and _in_slice(find_claim(chosen, row.claim_id)[1], only)]
        if not candidates:
            break
        row = candidates[0]
        figure, _ = find_claim(chosen, row.claim_id)
        episodes = math.ceil(row.target_pairs / len(figure.seeds))
        if progress:
            print(f"driveopt reproduce: deciding {row.claim_id} ({row.verdict}, {row.pairs} pairs): to {episodes} "
                  f"episodes per seed, about {_duration(row.cost)}", flush=True)
        reproduce(paper, out, figures=figures, episodes=episodes, claim=row.claim_id, workers=workers,
                  backend=backend, episode_fn=episode_fn, progress=progress)
        after = {r.claim_id: r.pairs for r in plan(paper, out, figures=figures)[0]}
        if after.get(row.claim_id, math.inf) <= row.pairs:
            stuck.add(row.claim_id)
        ran.append(row.claim_id)
    reproduce(paper, out, figures=figures, report_only=True, progress=progress)
    return ran


def _count(value: float) -> str:
    if math.isnan(value):
        return "-"
    return "never" if math.isinf(value) else f"{value:.0f}"


def _duration(seconds: float) -> str:
    if math.isnan(seconds):
        return "unknown"
    if math.isinf(seconds):
        return "beyond the protocol or never"
    return f"{seconds / 3600:.1f} h" if seconds >= 3600 else f"{seconds / 60:.0f} min"


def _seconds(seconds: float) -> str:
    return "unknown" if math.isnan(seconds) else f"{seconds:.0f} s"


def plan_text(paper: str, rows: list[PlanRow], claims: int) -> str:
    """The lines ``driveopt reproduce --plan`` prints: a header, then one line per undecided claim."""
    lines = [f"{paper}: {len(rows)} of {claims} claims undecided, cheapest decision first. Pairs: in all, for 80% power "
             "at the figure's final level, at the paper's stated size (- where it states none) and at the measured "
             "rates; cost: wall time of one worker for the pairs still needed, from the recorded episodes.",
             "claim | verdict | pairs | at the paper's size | at the measured rates | per pair | to decide"]
    for row in rows:
        lines.append(f"{row.claim_id} | {row.verdict} | {row.pairs}/{row.full_pairs} | {_count(row.paper_pairs)} | "
                     f"{_count(row.measured_pairs)} | {_seconds(row.seconds_per_pair)} | "
                     f"{_duration(row.cost)}")
    return "\n".join(lines) + "\n"


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
