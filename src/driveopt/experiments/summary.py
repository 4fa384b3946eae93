"""Summary statistics, tables and plots of benchmark records (P1 Fig. 7 style); the files are written whole or not
at all (:func:`driveopt.files.atomic_output`)."""

from __future__ import annotations

import csv
import math
import re
from collections import defaultdict
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from driveopt.experiments.store import StoreError
from driveopt.files import atomic_output

COLUMNS = (
    "scenario", "planner", "episodes", "collision_rate", "collision_ci_low", "collision_ci_high",
    "mean_speed_collision_free", "speed_std_collision_free", "mean_speed_all", "off_road_rate", "plan_ms_median",
    "plan_ms_p95", "sim_s_per_episode", "plan_s_per_episode", "reference", "faster_than_reference", "compared_with_reference",
)
REFERENCE = "idm"  # the planner every other one is compared with, episode by episode, when the records hold it
TIMING_DEVICE = "cpu"  # plan-time columns come from episodes planned on this JAX backend (records before it was kept: cpu)


def wilson_interval(successes: int, trials: int, z: float = 1.959964) -> tuple[float, float]:
    """95% Wilson score interval of a binomial proportion."""
    if trials == 0:
        return (math.nan, math.nan)
    p = successes / trials
    denom = 1.0 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denom
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denom
    # The interval holds p exactly (at p = 0 or 1 rounding would otherwise put a bound a hair on the wrong side of it).
    return (max(0.0, min(p, centre - half)), min(1.0, max(p, centre + half)))


def _faster(rs: list[dict[str, Any]], reference: dict[tuple[Any, ...], dict[str, Any]]) -> tuple[int, int]:
    """(episodes faster than the reference, episodes compared): those of ``rs`` that the reference also ran
    (same scenario, seed and episode, so the same traffic) and that neither collided in."""
    pairs = [(r, reference.get((r["scenario"], r["seed"], r["episode"]))) for r in rs]
    both = [(r, ref) for r, ref in pairs if ref is not None and not r["collided"] and not ref["collided"]]
    return sum(r["mean_speed"] > ref["mean_speed"] for r, ref in both), len(both)


def summarise(records: Iterable[dict[str, Any]], reference: str = REFERENCE) -> list[dict[str, Any]]:
    """One row per (scenario, planner), in first-seen order. Speeds [m/s]: mean episode speed, averaged
    over episodes; its standard deviation over the collision-free ones. Every planner but ``reference``
    is compared with it episode by episode where the records hold it (``faster_than_reference`` of
    ``compared_with_reference`` episodes, both collision-free). Plan and wall times come only from the episodes
    planned on :data:`TIMING_DEVICE` (a point may hold episodes run elsewhere for their outcomes; NaN when none).
    StoreError when two records (with seeds and episodes) are the same episode: it would be counted twice."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    episodes: set[tuple[Any, ...]] = set()
    for r in records:
        groups[(r["scenario"], r["planner"])].append(r)
        if "seed" in r and "episode" in r:
            key = (r["scenario"], r["planner"], r["seed"], r["episode"])
            if key in episodes:
                raise StoreError(f"the records hold {key[1]} on {key[0]}, seed {key[2]}, episode {key[3]} twice; "
                                 "each episode is counted once")
            episodes.add(key)
    by_episode = {(r["scenario"], r["seed"], r["episode"]): r for (_, planner), rs in groups.items() if planner == reference
                  for r in rs}
    rows = []
    for (scenario, planner), rs in groups.items():
        n = len(rs)
        crashed = sum(bool(r["collided"]) for r in rs)
        low, high = wilson_interval(crashed, n)
        free = [r["mean_speed"] for r in rs if not r["collided"]]
        faster, compared = _faster(rs, by_episode) if by_episode and planner != reference else (0, 0)
        # planning times of CPU episodes planned one at a time (a lock-step record's are shared calls' times)
        timed = [r for r in rs if r.get("device", TIMING_DEVICE) == TIMING_DEVICE and r.get("lockstep", 1) == 1]
        plan_ms = np.concatenate([np.asarray(r.get("plan_ms", []), float) for r in timed]) if timed else np.zeros(0)
        rows.append({
            "scenario": scenario,
            "planner": planner,
            "episodes": n,
            "collision_rate": crashed / n,
            "collision_ci_low": low,
            "collision_ci_high": high,
            "mean_speed_collision_free": float(np.mean(free)) if free else math.nan,
            "speed_std_collision_free": float(np.std(free)) if free else math.nan,
            "mean_speed_all": float(np.mean([r["mean_speed"] for r in rs])),
            "off_road_rate": sum(bool(r["off_road"]) for r in rs) / n,
            "plan_ms_median": float(np.median(plan_ms)) if plan_ms.size else math.nan,
            "plan_ms_p95": float(np.percentile(plan_ms, 95)) if plan_ms.size else math.nan,
            "sim_s_per_episode": float(np.mean([r["sim_seconds"] for r in timed])) if timed else math.nan,
            "plan_s_per_episode": float(np.mean([r["plan_seconds"] for r in timed])) if timed else math.nan,
            "reference": reference if compared else "",
            "faster_than_reference": faster,
            "compared_with_reference": compared,
        })
    return rows


def write_csv(rows: list[dict[str, Any]], path: str | Path) -> Path:
    """``rows`` as CSV with the :data:`COLUMNS` (a missing number is ``nan``), replacing ``path`` whole."""
    path = Path(path)
    with atomic_output(path) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return path


def markdown_table(rows: list[dict[str, Any]]) -> str:
    head = ("| scenario | planner | episodes | collision rate (95% CI) | speed, collision-free [m/s] (std) | speed, all [m/s] "
            "| faster than reference | off-road | plan ms median / p95 | wall s/episode: sim + plan |")
    lines = [head, "|" + "---|" * 10]

    def ms(value: float) -> str:
        return "-" if math.isnan(value) else f"{value:.0f}"

    def seconds(value: float) -> str:
        return "-" if math.isnan(value) else f"{value:.1f}"

    def speed(r: dict[str, Any]) -> str:  # no collision-free episode: no speed to show
        mean, std = r["mean_speed_collision_free"], r["speed_std_collision_free"]
        return "-" if math.isnan(mean) else f"{mean:.2f} ({std:.2f})"

    def faster(r: dict[str, Any]) -> str:
        return f"{r['faster_than_reference']}/{r['compared_with_reference']} ({r['reference']})" if r["reference"] else "-"

    for r in rows:
        lines.append(
            f"| {r['scenario']} | {r['planner']} | {r['episodes']} | {r['collision_rate']:.2f} "
            f"({r['collision_ci_low']:.2f}-{r['collision_ci_high']:.2f}) | {speed(r)} "
            f"| {r['mean_speed_all']:.2f} | {faster(r)} | {r['off_road_rate']:.2f} | "
            f"{ms(r['plan_ms_median'])} / {ms(r['plan_ms_p95'])} | "
            f"{seconds(r['sim_s_per_episode'])} + {seconds(r['plan_s_per_episode'])} |"
        )
    return "\n".join(lines) + "\n"


def _family_and_density(scenario: str) -> tuple[str, float | None]:
    """('four-lane', 3.0) from 'four-lane-d3.0' (variant suffixes stay in the family name)."""
    match = re.match(r"^(.*?)-d(\d+(?:\.\d+)?)(.*)$", scenario)
    if not match:
        return scenario, None
    return match.group(1) + match.group(3), float(match.group(2))


def plot_summary(rows: list[dict[str, Any]], path: str | Path) -> Path:
    """Collision rate (with 95% CI) and collision-free speed against density, one panel pair per road, written to
    ``path`` whole (format by extension)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    families: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        family, density = _family_and_density(r["scenario"])
        families[family].append({**r, "density": density if density is not None else 0.0})
    fig, axes = plt.subplots(2, max(1, len(families)), figsize=(5.5 * max(1, len(families)), 7), squeeze=False)
    for col, (family, rs) in enumerate(sorted(families.items())):
        planners = sorted({r["planner"] for r in rs})
        width = 0.8 / max(1, len(planners))
        densities = sorted({r["density"] for r in rs})
        for j, planner in enumerate(planners):
            pts = sorted((r for r in rs if r["planner"] == planner), key=lambda r: r["density"])
            xs = np.array([densities.index(r["density"]) for r in pts]) + (j - (len(planners) - 1) / 2) * width
            rate = np.array([100 * r["collision_rate"] for r in pts])
            err = np.array([[100 * (r["collision_rate"] - r["collision_ci_low"]) for r in pts],
                            [100 * (r["collision_ci_high"] - r["collision_rate"]) for r in pts]])
            axes[0, col].bar(xs, rate, width, yerr=err, capsize=2, label=planner)
            axes[1, col].bar(xs, [r["mean_speed_collision_free"] for r in pts], width, label=planner)
        for row, label in ((0, "collision rate [%]"), (1, "mean speed, collision-free [m/s]")):
            ax = axes[row, col]
            ax.set_xticks(range(len(densities)), [f"{d:g}" for d in densities])
            ax.set_xlabel("density")
            ax.set_ylabel(label)
            ax.set_title(family)
        axes[0, col].legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    try:
        with atomic_output(path) as tmp:
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)
    return path
