"""The report of ``driveopt reproduce``: ``report.md`` and ``report.json`` (the same numbers, strict JSON) with one
row per claim, and one PNG per figure (collision rate with its 95% Wilson interval and collision-free mean speed with
its 95% bootstrap interval, per scenario and arm). The report opens with one line per claim of the paper (what the
paper states, the faithful and the strengthened measurement, the interval the verdict rests on, pairs, verdicts);
every row says whether it compares the papers' methods as their authors ran them ("faithful"), driveopt's planners
("driveopt") or one with the other, and the level and look it was judged at. Verdicts are tallied once per distinct
test (a test several figures print, or several claims share, counts once). ``report.json`` lists, per claim, the
records it used: folders, episodes, and their code digests, jax and numpy versions, processors and devices. Every
file is replaced whole."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from driveopt.experiments.protocols import DRIVEOPT_ROW, FAITHFUL_ROW, MIXED_ROW, PLAN_TIME, FigureProtocol
from driveopt.experiments.protocols import COLLISIONS, LOOK_FRACTIONS, SPEED
from driveopt.experiments.verdicts import (
    ALPHA,
    COLLISION_MARGIN,
    CONTRADICTED,
    MIN_PAIRS,
    RELATIVE_MARGIN,
    ArmStats,
    ClaimResult,
)
from driveopt.files import atomic_output, atomic_write, write_json

PAPER_TITLES = {
    "p1": "P1: Bi-Level Optimization Augmented with Conditional Variational Autoencoder for Autonomous Driving in Dense "
          "Traffic",
    "p2": "P2: Learning Sampling Distribution and Safety Filter for Autonomous Driving with VQ-VAE and Differentiable "
          "Optimization",
}


def _num(value: float, digits: int = 2) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def _interval(low: float, high: float, digits: int = 2) -> str:
    """`` [low, high]`` of a difference (either sign); empty when there is none (too few pairs)."""
    return "" if math.isnan(low) or math.isnan(high) else f" [{low:.{digits}f}, {high:.{digits}f}]"


def _p(value: float) -> str:
    return "-" if math.isnan(value) else (f"{value:.3f}" if value >= 0.001 else f"{value:.1e}")


VERSION_MARK = {"paper-faithful": "F", "driveopt-strengthened": "S", "reference": "R"}


def _arm_cell(a: ArmStats, plan: bool) -> str:
    if not a.episodes:
        return f"`{a.label}` [{VERSION_MARK.get(a.version, a.version)}]: no episodes"
    cell = (f"`{a.label}` [{VERSION_MARK.get(a.version, a.version)}]: {a.collisions}/{a.episodes} collided, "
            f"{_num(a.collision_rate)} ({_num(a.collision_low)}-{_num(a.collision_high)}); {_num(a.speed)} "
            f"({_num(a.speed_low)}-{_num(a.speed_high)}) m/s")
    return cell + (f"; plan {_num(a.plan_ms, 1)} ms" if plan else "")


def _arms_legend(results: list[ClaimResult]) -> list[str]:
    """One line per arm of a figure: its version and how it departs from the paper's method."""
    seen: dict[str, ArmStats] = {}
    for r in results:
        seen.setdefault(r.arm.label, r.arm)
        seen.setdefault(r.baseline.label, r.baseline)
    return [f"- `{label}`: {a.version}{' (' + a.note + ')' if a.note else ''}" for label, a in seen.items()]


def _paired(r: ClaimResult) -> str:
    """The paired tests' cell of a row ("-" without pairs); plan time only on a plan-time row."""
    if not r.pairs:
        return "-"
    text = (f"collisions only arm / only baseline {r.only_arm_collided} / {r.only_baseline_collided}, McNemar p "
            f"{_p(r.mcnemar_p)}, rate difference{_interval(r.collision_difference_low, r.collision_difference_high) or ' -'}; "
            f"speed: arm faster in {r.arm_faster}/{r.speed_sign_n}, sign p {_p(r.speed_sign_p)}, "
            f"diff {_num(r.speed_difference)}{_interval(r.speed_difference_low, r.speed_difference_high)} m/s")
    if r.metric == PLAN_TIME:
        text += (f"; plan time on {', '.join(r.processors) or 'no one processor'}: arm quicker in "
                 f"{r.arm_quicker}/{r.plan_sign_n}, sign p {_p(r.plan_sign_p)}, diff {_num(r.plan_difference, 1)}"
                 f"{_interval(r.plan_difference_low, r.plan_difference_high, 1)} ms")
        left = [f"{n} {why}" for n, why in ((r.plan_pairs_unnamed, "naming no processor"),
                                             (r.plan_pairs_mixed, "of two processors")) if n]
        if left:
            text += f" ({' and '.join(left)} left out)"
    return text


def _episodes(r: ClaimResult) -> str:
    return f"{r.pairs} pairs, seeds {', '.join(map(str, r.seeds))}"


def verdict_cell(r: ClaimResult) -> str:
    """The verdict, bold, with its look, level, interval and the pairs still needed."""
    text = f"**{r.verdict}**"
    if r.verdict == "not run":
        return text
    text += " (interim)" if r.interim else ""
    where = (f"look {r.look} pairs, level {r.level:.2g}" if r.look else "below the first look")
    if not math.isnan(r.holm_p):
        where += f", Holm p {_p(r.holm_p)}"
    text += f"; {where}" + ("; primary" if r.primary else "")
    if r.detail:
        text += f"; {r.detail}"
    if math.isfinite(r.pairs_needed) and r.pairs_needed > 0 and r.detail and "pairs" not in r.detail:
        text += f"; {r.pairs_needed:.0f} more pairs"
    return text


def claim_row(r: ClaimResult) -> str:
    episodes = _episodes(r)
    if r.reduced:
        episodes += f" (reduced: the full protocol has {r.full_pairs})"
    like = "" if r.like_for_like else " (not like for like)"
    plan = r.metric == PLAN_TIME
    return (f"| {r.scenario} | {r.kind} | {r.metric}: arm {r.expect}{like} | {r.paper} | {_arm_cell(r.arm, plan)} | "
            f"{_arm_cell(r.baseline, plan)} | {_paired(r)} | {episodes} | {verdict_cell(r)} |")


def distinct_tests(results: list[ClaimResult]) -> list[ClaimResult]:
    """One row per distinct test (``ClaimResult.test_key``; a row without a key is its own test), the first printed."""
    seen: set[str] = set()
    kept = []
    for i, r in enumerate(results):
        key = r.test_key or f"row {i}"
        if key not in seen:
            seen.add(key)
            kept.append(r)
    return kept


def effect_text(r: ClaimResult) -> str:
    """The paper's stated effect: a ratio, levels, or its direction."""
    e = r.effect
    if e.ratio is not None:
        low, high = e.ratio
        fewer = f"{1 / high:.3g}x" if low == high else f"{1 / high:.3g}-{1 / low:.3g}x"
        return f"rate ratio {low:.3g}-{high:.3g} ({fewer} fewer)" if low != high else f"rate ratio {low:.3g} ({fewer} fewer)"
    parts = [f"{who} {low:.0%}" + ("" if low == high else f"-{high:.0%}")
             for who, bounds in (("arm", e.arm_level), ("baseline", e.baseline_level)) if bounds for low, high in [bounds]]
    return ", ".join(parts) if parts else f"direction: arm {r.expect}"


def _measured(r: ClaimResult) -> str:
    if not r.pairs:
        return "not run"
    if r.metric == COLLISIONS:
        return f"{r.arm.collisions}/{r.pairs} vs {r.baseline.collisions}/{r.pairs} collided"
    if r.metric == SPEED:
        return f"{r.speed_difference:+.2f} m/s" if not math.isnan(r.speed_difference) else "no collision-free pair"
    return f"{r.plan_difference:+.1f} ms" if not math.isnan(r.plan_difference) else "no compared pair"


def _representative(rows: list[ClaimResult]) -> ClaimResult:
    """The row a summary line quotes: the figure's primary claim if among them, else the one with the most pairs."""
    return next((r for r in rows if r.primary), max(rows, key=lambda r: r.pairs))


def _side(rows: list[ClaimResult]) -> tuple[str, str]:
    """(measurement, interval) cells of one side (faithful or strengthened) of a paper claim."""
    if not rows:
        return "-", "-"
    r = _representative(rows)
    cell = f"{_measured(r)} (`{r.arm.planner}` vs `{r.baseline.planner}`)"
    if len(rows) > 1:
        cell += f"; {len(rows)} rows"
    interval = "-" if math.isnan(r.verdict_low) else f"[{r.verdict_low:.2f}, {r.verdict_high:.2f}]"
    return cell, interval


def _tally(rows: list[ClaimResult]) -> str:
    counts: dict[str, int] = {}
    for r in rows:
        verdict = r.verdict + (" (interim)" if r.interim and r.verdict not in ("inconclusive", "not run") else "")
        counts[verdict] = counts.get(verdict, 0) + 1
    return ", ".join(f"{n} {v}" for v, n in sorted(counts.items())) or "-"


def paper_claims(results: list[ClaimResult]) -> list[str]:
    """The report's opening table: one line per claim of the paper (figure, its words, metric), the faithful rows
    (both arms as their authors ran them) beside driveopt's (strengthened, or strengthened against a faithful agent)."""
    groups: dict[tuple[str, str, str], list[ClaimResult]] = {}
    for r in results:
        groups.setdefault((r.figure, r.paper, r.metric), []).append(r)
    lines = ["| figure | the paper | paper's value | ours, faithful | ours, strengthened | interval (F; S) | pairs | "
             "verdicts (F; S) |", "|---|---|---|---|---|---|---|---|"]
    for (figure, paper, metric), rows in groups.items():
        faithful = [r for r in rows if r.kind == FAITHFUL_ROW]
        strong = [r for r in rows if r.kind != FAITHFUL_ROW]
        (f_cell, f_int), (s_cell, s_int) = _side(faithful), _side(strong)
        pairs = sorted({r.pairs for r in rows})
        span = f"{pairs[0]}" if len(pairs) == 1 else f"{pairs[0]}-{pairs[-1]}"
        lines.append(f"| {figure} | {paper} ({metric}) | {effect_text(rows[0])} | {f_cell} | {s_cell} | {f_int}; {s_int} "
                     f"| {span} of {rows[0].full_pairs} | {_tally(faithful)}; {_tally(strong)} |")
    return lines


def _questions(answers: list[ClaimResult]) -> list[str]:
    """The section of the pooled questions: per question, one row per metric with its answer."""
    if not answers:
        return []
    lines = ["## Pooled questions", "",
             "A question the papers leave open, answered on every episode pair of the claims that bear on it, pooled "
             "over their figures and settings (an episode of the same two arms on the same scenario counts once): "
             f"does the arm change the metric? Paired tests two-sided at α = {ALPHA}; plan times mix the settings' "
             "sample counts (the sign test compares each pair).", ""]
    for title in dict.fromkeys(r.paper for r in answers):
        rows = [r for r in answers if r.paper == title]
        need = rows[0].full_pairs
        lines += [f"### {title[0].upper()}{title[1:]}", "", f"Needs at least {need} pairs.", "",
                  "| metric | arm | baseline | paired tests | episodes | answer |", "|---|---|---|---|---|---|"]
        lines += [f"| {r.metric} | {_arm_cell(r.arm, r.metric == PLAN_TIME)} | {_arm_cell(r.baseline, r.metric == PLAN_TIME)} "
                  f"| {_paired(r)} | {_episodes(r)} | **{r.verdict}** |" for r in rows]
        lines.append("")
    return lines


def verdict_counts(results: list[ClaimResult]) -> dict[str, int]:
    """Verdicts counted once per distinct test (:func:`distinct_tests`); a decided interim verdict counts apart."""
    counts: dict[str, int] = {}
    for r in distinct_tests(results):
        verdict = r.verdict + (" (interim)" if r.interim and r.verdict not in ("inconclusive", "not run") else "")
        counts[verdict] = counts.get(verdict, 0) + 1
    return dict(sorted(counts.items()))


def _verdict_counts(results: list[ClaimResult]) -> str:
    return ", ".join(f"{v}: {n}" for v, n in verdict_counts(results).items()) or "none"


UNEXPLAINED = ("**not explained yet**: trace episodes where the arms differ (`driveopt trace-episode`) and record "
               "the finding in the claim's explanation (`src/driveopt/experiments/protocols.py`)")


def _contradictions(rows: list[ClaimResult]) -> list[str]:
    """Under a figure's table: every contradicted claim with why driveopt's result may differ and what settles it."""
    lines = [f"- {r.scenario}, {r.metric}, `{r.arm.label}` against `{r.baseline.label}`: {r.explanation or UNEXPLAINED}"
             for r in rows if r.verdict == CONTRADICTED]
    return ["Contradicted claims:", "", *lines, ""] if lines else []


def _code_line(versions: dict[str, int]) -> str:
    """Which driveopt sources ran a figure's episodes: more than one means its rows mix code versions."""
    if not versions:
        return "Records: none yet."
    parts = [f"{n} on driveopt source `{code}`" if code != "unrecorded" else f"{n} without a code digest"
             for code, n in sorted(versions.items(), key=lambda item: -item[1])]
    mixed = " (**more than one code version**)" if len(versions) > 1 else ""
    return f"Records: {sum(versions.values())} episodes, {', '.join(parts)}{mixed}."


def markdown(paper: str, figures: tuple[FigureProtocol, ...], results: list[ClaimResult],
             code: dict[str, dict[str, int]] | None = None, answers: list[ClaimResult] | None = None) -> str:
    looks = ", ".join(f"{f:.0%}" for f in LOOK_FRACTIONS)
    lines = [f"# Reproduction of {PAPER_TITLES.get(paper, paper)}", "",
             "Written by `driveopt reproduce`. Each row compares the arm with the baseline on the same episodes (same "
             "scenario, seed and episode). Rates with 95% Wilson intervals, speeds (collision-free episodes) with 95% "
             "bootstrap intervals, paired differences with t intervals, plan time the median per call, compared only "
             "between records of one processor model.",
             f"Verdict rule: each claim on the paper's stated effect: a ratio of collision rates (McNemar's exact test "
             f"for the direction, a conservative rate-ratio interval for the size), levels (each stated arm's Wilson "
             f"interval), or a direction (the paired test); 'no worse' claims by the paired difference's interval "
             f"against a margin of {COLLISION_MARGIN:.2f} in collision rate or {RELATIVE_MARGIN:.0%} of the "
             f"baseline's mean speed or plan time (none below {MIN_PAIRS} pairs). Each figure's claims are read at "
             f"looks of {looks} of the protocol's pairs, at O'Brien-Fleming levels (overall α = {ALPHA}), "
             f"**interim** before the last; one primary claim per figure, the others at Holm-adjusted levels. See "
             "docs/reproduction/README.md.", "", "## The paper's claims", "",
             "One line per claim of the paper: what it states, the faithful rows (its methods as their authors ran "
             "them) and driveopt's (quoting the figure's primary claim where it is among them, else the row with the "
             "most pairs), the interval that row's verdict rests on, the pairs, and every row's verdict.", "",
             *paper_claims(results), ""]
    lines.append("Rows: **faithful** compares the papers' methods as the papers and their authors' code ran them "
                 "(the `*-faithful` planners, P1's RL agents), **driveopt** compares driveopt's strengthened planners, "
                 f"**{MIXED_ROW}** one with the other.")
    lines.append("")
    unexplained = sum(r.verdict == CONTRADICTED and not r.explanation for r in results)
    tests = len(distinct_tests(results))
    lines.append(f"Verdicts of the {tests} distinct tests ({len(results)} rows): {_verdict_counts(results)}."
                 + (f" **{unexplained} contradicted without an explanation yet** (listed under their figures)."
                    if unexplained else ""))
    for kind in (FAITHFUL_ROW, DRIVEOPT_ROW, MIXED_ROW):
        rows = [r for r in results if r.kind == kind]
        if rows:
            lines.append(f"- {kind} rows: {_verdict_counts(rows)}.")
    lines.append("")
    lines += _questions(answers or [])
    head = ("| scenario | row | claim | paper | arm | baseline | paired tests | episodes | verdict |\n"
            "|---|---|---|---|---|---|---|---|---|")
    for figure in figures:
        lines.append(f"## {figure.figure}: {figure.title}")
        lines.append("")
        if figure.not_run:
            lines.append(f"Not run: {figure.not_run}.")
            lines.append("")
            continue
        protocol = (f"Protocol: seeds {', '.join(map(str, figure.seeds))}, {figure.episodes} episodes per seed, "
                    f"episodes of {'the scenario' if figure.duration is None else f'{figure.duration:g} s'}"
                    f"{'; reduced (quick or fewer episodes than the full protocol)' if figure.reduced else ''}.")
        rows = [r for r in results if r.figure == figure.figure]
        if code is not None:
            protocol += " " + _code_line(code.get(figure.figure, {}))
        primary = next((r for r in rows if r.primary), None)
        if primary is not None:
            protocol += (f" Looks at {', '.join(map(str, figure.look_pairs))} pairs; primary claim `{primary.claim_id}`, "
                         f"the others Holm-adjusted.")
        processors = sorted({p for r in rows if r.metric == PLAN_TIME for p in r.processors})
        if any(r.metric == PLAN_TIME for r in rows):
            unnamed = sum(r.plan_pairs_unnamed for r in rows if r.metric == PLAN_TIME)
            protocol += (f" Plan times compared on {', '.join(processors) or 'no processor yet'}"
                         + (f"; {unnamed} pairs whose records name no processor left out" if unnamed else "") + ".")
        lines += [protocol, "", "Arms ([F] paper-faithful, [S] driveopt-strengthened, [R] reference):", *_arms_legend(rows),
                  "", head]
        lines += [claim_row(r) for r in rows]
        lines += ["", *_contradictions(rows), f"![{figure.figure}]({figure.figure}.png)", ""]
    return "\n".join(lines) + "\n"


def report_json(paper: str, figures: tuple[FigureProtocol, ...], results: list[ClaimResult],
                code: dict[str, dict[str, int]] | None = None, answers: list[ClaimResult] | None = None) -> dict[str, Any]:
    return {
        "paper": paper,
        "rule": {"alpha": ALPHA, "collision_margin": COLLISION_MARGIN, "relative_margin": RELATIVE_MARGIN,
                 "min_pairs": MIN_PAIRS, "look_fractions": list(LOOK_FRACTIONS)},
        "verdicts": verdict_counts(results),  # once per distinct test
        "tests": len(distinct_tests(results)),
        "figures": [{"figure": f.figure, "title": f.title, "seeds": list(f.seeds), "episodes": f.episodes,
                     "duration_s": f.duration, "reduced": f.reduced, "not_run": f.not_run or None,
                     "primary": f.primary or None, "looks": list(f.look_pairs) if f.claims else [],
                     "code": (code or {}).get(f.figure, {}),
                     "claims": [r.to_dict() for r in results if r.figure == f.figure]} for f in figures],
        "questions": [r.to_dict() for r in answers or []],
    }


def plot_figure(figure: FigureProtocol, results: list[ClaimResult], path: Path) -> Path | None:
    """Collision rate [%] and collision-free speed [m/s] with 95% intervals of every (scenario, arm) of the figure's
    claims; None (nothing written) for a figure without claims."""
    arms: dict[tuple[str, str], ArmStats] = {}
    for r in results:
        if r.figure == figure.figure:
            arms.setdefault((r.scenario, r.arm.label), r.arm)
            arms.setdefault((r.scenario, r.baseline.label), r.baseline)
    if not arms:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    keys = sorted(arms)  # by scenario, then arm
    x = np.arange(len(keys))
    fig, axes = plt.subplots(2, 1, figsize=(max(6.0, 0.45 * len(keys) + 2), 7.5), sharex=True)

    def bars(ax, values, lows, highs, label):
        v = np.asarray(values, float)
        err = np.nan_to_num(np.vstack([v - np.asarray(lows, float), np.asarray(highs, float) - v]), nan=0.0)
        ax.bar(x, np.nan_to_num(v), yerr=np.clip(err, 0, None), capsize=2, color="tab:blue")
        ax.set_ylabel(label)

    stats = [arms[k] for k in keys]
    bars(axes[0], [100 * a.collision_rate for a in stats], [100 * a.collision_low for a in stats],
         [100 * a.collision_high for a in stats], "collision rate [%]")
    bars(axes[1], [a.speed for a in stats], [a.speed_low for a in stats], [a.speed_high for a in stats],
         "speed, collision-free [m/s]")
    axes[1].set_xticks(x, [f"{s}\n{label}" for s, label in keys], rotation=70, ha="right", fontsize=7)
    axes[0].set_title(f"{figure.paper} {figure.figure}: {figure.title}", fontsize=9)
    fig.tight_layout()
    try:
        with atomic_output(path) as tmp:
            fig.savefig(tmp, dpi=100, format="png")
    finally:
        plt.close(fig)
    return path


def write_report(paper: str, figures: tuple[FigureProtocol, ...], results: list[ClaimResult], out: Path,
                 code: dict[str, dict[str, int]] | None = None, answers: list[ClaimResult] | None = None) -> None:
    """report.md, report.json and ``<figure>.png`` of every figure with claims, in ``out``. code: ``{figure: {source
    digest: episodes}}`` (:func:`driveopt.experiments.reproduce.code_versions`); answers: the pooled questions' rows
    (:func:`driveopt.experiments.reproduce.answer_questions`)."""
    atomic_write(out / "report.md", markdown(paper, figures, results, code, answers).encode())
    write_json(out / "report.json", report_json(paper, figures, results, code, answers))
    for figure in figures:
        plot_figure(figure, results, out / f"{figure.figure}.png")
