"""The report of ``driveopt reproduce``: ``report.md`` and ``report.json`` (the same numbers, strict JSON) with one
row per claim, and one PNG per figure (collision rate with its 95% Wilson interval and collision-free mean speed with
its 95% bootstrap interval, per scenario and arm). Every row says whether it compares the papers' methods as their
authors ran them ("faithful"), driveopt's planners ("driveopt") or one with the other. Every file is replaced whole."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from driveopt.experiments.protocols import DRIVEOPT_ROW, FAITHFUL_ROW, MIXED_ROW, PLAN_TIME, FigureProtocol
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
        text += (f"; plan time: arm quicker in {r.arm_quicker}/{r.plan_sign_n}, sign p {_p(r.plan_sign_p)}, diff "
                 f"{_num(r.plan_difference, 1)}{_interval(r.plan_difference_low, r.plan_difference_high, 1)} ms")
    return text


def _episodes(r: ClaimResult) -> str:
    return f"{r.pairs} pairs, seeds {', '.join(map(str, r.seeds))}"


def claim_row(r: ClaimResult) -> str:
    episodes = _episodes(r)
    if r.reduced:
        episodes += f" (reduced: the full protocol has {r.full_pairs})"
    like = "" if r.like_for_like else " (not like for like)"
    plan = r.metric == PLAN_TIME
    return (f"| {r.scenario} | {r.kind} | {r.metric}: arm {r.expect}{like} | {r.paper} | {_arm_cell(r.arm, plan)} | "
            f"{_arm_cell(r.baseline, plan)} | {_paired(r)} | {episodes} | **{r.verdict}** |")


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


def _verdict_counts(results: list[ClaimResult]) -> str:
    counts: dict[str, int] = {}
    for r in results:
        counts[r.verdict] = counts.get(r.verdict, 0) + 1
    return ", ".join(f"{v}: {n}" for v, n in sorted(counts.items())) or "none"


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
    lines = [f"# Reproduction of {PAPER_TITLES.get(paper, paper)}", "",
             "Written by `driveopt reproduce`. Each row compares the arm with the baseline on the same episodes (same "
             "scenario, seed and episode). Rates with 95% Wilson intervals, speeds (collision-free episodes) with 95% "
             "bootstrap intervals, plan time the median per call.",
             f"Verdict rule: paired exact tests at α = {ALPHA} (McNemar on collisions, sign test on speed and plan "
             f"time) for 'better'/'worse' claims; for 'no worse' claims the paired difference's interval against a "
             f"margin of {COLLISION_MARGIN:.2f} in collision rate or {RELATIVE_MARGIN:.0%} of the baseline's mean speed "
             f"or plan time (at least {MIN_PAIRS} pairs). See docs/reproduction/README.md.", ""]
    lines.append("Rows: **faithful** compares the papers' methods as the papers and their authors' code ran them "
                 "(the `*-faithful` planners, P1's RL agents), **driveopt** compares driveopt's strengthened planners, "
                 f"**{MIXED_ROW}** one with the other.")
    lines.append("")
    unexplained = sum(r.verdict == CONTRADICTED and not r.explanation for r in results)
    lines.append(f"Verdicts: {_verdict_counts(results)}."
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
                 "min_pairs": MIN_PAIRS},
        "figures": [{"figure": f.figure, "title": f.title, "seeds": list(f.seeds), "episodes": f.episodes,
                     "duration_s": f.duration, "reduced": f.reduced, "not_run": f.not_run or None,
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
