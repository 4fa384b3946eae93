"""P2's closed-loop figures as resumable sweeps of ``driveopt bench`` (issues 14 and 15).

    python benchmarks/p2_closed_loop.py --figure fig7|fig8a|fig8b|fig9 --out DIR [--episodes N] [--workers 2]
        [--planners P ...] [--scenarios S ...] [--x V ...] [--cvae-weights FILE] [--vqvae-weights FILE] [--filter-weights FILE] [--duration S] [--records DIR] [--list]

Figures (P2's traffic, :mod:`driveopt.sim.scenarios` ``p2-*``; 1000 samples; seed 42):

* ``fig7``: ``cvae-filter``, ``cvae``, ``vqvae`` and ``vqvae-cem`` on ``p2-four-lane-d3.0`` (density 3, limit
  15 m/s) and ``p2-four-lane-d1.5-slow`` (density 1.5, limit 7 m/s); 50 episodes. With them, at their own sample
  counts, the references ``bilevel-p1`` (issue 14's stall criterion: a P2 planner *stalls* in an episode it
  finishes without collision at under 2.5 m/s where ``bilevel-p1`` finishes it above 6 m/s; each row counts them
  as ``stalls`` of ``stall_episodes`` comparable ones) and ``idm``.
* ``fig8a``: the learned filter (``vqvae-filter``) against the plain barrier filter (``vqvae``) for
  ``projection.max_iterations`` 10, 25, 50 and 100 on ``p2-four-lane-d3.0``; 30 episodes, 50 at 100.
* ``fig8b``: the same pair for 250, 500, 750 and 1000 samples at 100 iterations; 30 episodes, 50 at 1000 (fig8a's
  100-iteration points).
* ``fig9``: ``cvae-filter`` and ``vqvae-filter`` with their filter and without (``max_iterations`` 0: the
  samples ranked as drawn) at densities 1.0, 1.5 and 3.0; 30 episodes.

``--episodes`` replaces every point's count; ``--planners`` runs only those planners' points, in the order given
(e.g. a first look at ``vqvae`` against ``cvae-filter``; the others follow on a later run without it);
``--scenarios`` only the points on those roads. Each point is one ``driveopt bench`` folder under ``--out``,
named by its settings, so figures share the points they have in common (a point's summary covers its own
episode count, the first N of the folder) and a rerun resumes every point where it stopped. After every point ``DIR/<figure>.json`` (the bench summary row of each point with its
settings, for plotting elsewhere) and ``DIR/<figure>.png`` (collision rate with its 95% interval, speed over
collision-free episodes with its standard deviation, and median planning time per call, against the swept
value) are rewritten, so a partial sweep can be looked at. Weights default to the shipped ones; a file that
is missing, or that a planner cannot use on the road, stops the sweep with a one-line error (status 2)
before anything runs.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
from pathlib import Path
from typing import Any, NamedTuple

from driveopt.cli import stop_cleanly_on_signals
from driveopt.errors import DriveoptError
from driveopt.experiments.bench import BenchSpec, run_bench
from driveopt.files import write_json

SAMPLES = 1000  # [-] P2's sample count
DEFAULT_ITERATIONS = 100  # [-] projection.max_iterations of vqvae, vqvae-filter and cvae-filter (P2)
DENSE, SLOW = "p2-four-lane-d3.0", "p2-four-lane-d1.5-slow"
STALL_REFERENCE = "bilevel-p1"  # issue 14: no episode under STALL_SPEED where this planner drives above REFERENCE_SPEED
STALL_SPEED, REFERENCE_SPEED = 2.5, 6.0  # [m/s] mean speeds of an episode


class Point(NamedTuple):
    """One bench run of a sweep: ``x`` is the swept value on the figure's axis, ``variant`` its line."""

    scenario: str
    planner: str
    samples: int | None  # None: the planner's own (the references)
    iterations: int | None  # projection.max_iterations (None: the planner's own, 100 for P2's pipelines)
    episodes: int
    variant: str
    x: float | str

    @property
    def folder(self) -> str:
        its = "default" if self.iterations is None else str(self.iterations)
        samples = "default" if self.samples is None else str(self.samples)
        return f"{self.scenario}--{self.planner}--n{samples}--k{its}"


def _iterations(k: int) -> int | None:
    """The override for ``k`` filter iterations: none for P2's 100, the planners' default, so that equal runs share a folder."""
    return None if k == DEFAULT_ITERATIONS else k


def points(figure: str, episodes: int | None = None, planners: list[str] | None = None,
           scenarios: list[str] | None = None, xs: list[str] | None = None) -> list[Point]:
    """The points of ``figure``; ``episodes`` replaces every point's episode count; ``planners`` keeps only theirs,
    in the order given; ``scenarios`` only those on these roads; ``xs`` only those at these values of the figure's
    axis (as written: ``25`` iterations, ``500`` samples, ``1.5`` density, a scenario's name)."""
    learned_vs_plain = (("learned", "vqvae-filter"), ("plain", "vqvae"))
    if figure == "fig7":
        out = [Point(s, p, None, None, 50, p, s) for s in (DENSE, SLOW) for p in (STALL_REFERENCE, "idm")]  # cheap: first
        out += [Point(s, p, SAMPLES, None, 50, p, s) for s in (DENSE, SLOW) for p in ("cvae-filter", "cvae", "vqvae", "vqvae-cem")]
    elif figure == "fig8a":
        out = [Point(DENSE, p, SAMPLES, _iterations(k), 50 if k == 100 else 30, v, k) for k in (10, 25, 50, 100)
               for v, p in learned_vs_plain]
    elif figure == "fig8b":
        out = [Point(DENSE, p, n, None, 50 if n == SAMPLES else 30, v, n) for n in (250, 500, 750, SAMPLES) for v, p in learned_vs_plain]
    elif figure == "fig9":
        out = [Point(f"p2-four-lane-d{d}", p, SAMPLES, k, 30, f"{p}{'' if k is None else ' without filter'}", d)
               for d in ("1.0", "1.5", "3.0") for p in ("cvae-filter", "vqvae-filter") for k in (None, 0)]
    else:
        raise DriveoptError(f"unknown figure {figure!r}: fig7, fig8a, fig8b or fig9")
    if planners:
        known = sorted({pt.planner for pt in out})
        unknown = sorted(set(planners) - set(known))
        if unknown:
            raise DriveoptError(f"{figure} has no points of {', '.join(unknown)}; its planners: {', '.join(known)}")
        out = sorted((pt for pt in out if pt.planner in planners), key=lambda pt: planners.index(pt.planner))
    if scenarios:
        known = sorted({pt.scenario for pt in out})
        unknown = sorted(set(scenarios) - set(known))
        if unknown:
            raise DriveoptError(f"{figure} has no points on {', '.join(unknown)}; its scenarios: {', '.join(known)}")
        out = [pt for pt in out if pt.scenario in scenarios]
    if xs:
        known = sorted({str(pt.x) for pt in out})
        unknown = sorted(set(xs) - set(known))
        if unknown:
            raise DriveoptError(f"{figure} has no points at {', '.join(unknown)}; its values: {', '.join(known)}")
        out = [pt for pt in out if str(pt.x) in xs]
    return [pt._replace(episodes=episodes) for pt in out] if episodes else out


def bench_spec(point: Point, weights: dict[str, str | None], duration: float | None) -> BenchSpec:
    """The ``driveopt bench`` run of ``point``: its prior's weights (``cvae``/``vqvae``) and, for ``vqvae-filter``,
    the filter's, when given; the iteration count as a config override."""
    options: dict[str, Any] = {} if point.samples is None else {"samples": point.samples}
    prior = next((p for p in ("cvae", "vqvae") if point.planner.startswith(p)), None)
    if prior and weights.get(prior):
        options["weights"] = weights[prior]
    config: dict[str, Any] = {}
    if point.iterations is not None:
        config["projection"] = {"max_iterations": point.iterations}
    if point.planner == "vqvae-filter" and weights.get("filter"):
        config["safety_filter"] = {"weights": weights["filter"]}
    if config:
        options["config"] = config
    if duration is not None:
        options["duration"] = duration
    return BenchSpec((point.scenario,), (point.planner,), (42,), point.episodes, options)


def episode_speeds(folder: Path, episodes: int) -> dict[int, float | None]:
    """Mean speed [m/s] of each of the first ``episodes`` episodes of a bench folder; None for one that collided."""
    speeds = {}
    with open(folder / "episodes.jsonl") as f:
        for line in f:
            record = json.loads(line)
            if record["episode"] < episodes:
                speeds[record["episode"]] = None if record["collided"] else record["mean_speed"]
    return speeds


def stalls(speeds: dict[int, float | None], reference: dict[int, float | None]) -> tuple[int, int]:
    """(stalls, comparable episodes): episodes both finish without collision, and of those the ones where the planner's
    mean speed is under :data:`STALL_SPEED` while the reference's is above :data:`REFERENCE_SPEED`."""
    both = [e for e in speeds if speeds[e] is not None and reference.get(e) is not None]
    return sum(speeds[e] < STALL_SPEED and reference[e] > REFERENCE_SPEED for e in both), len(both)


def figure_rows(pts: list[Point], rows: dict[Point, dict[str, Any]], out: Path | None = None) -> list[dict[str, Any]]:
    """The JSON rows of a figure: each finished point's settings and its bench summary row, and, where the stall
    reference has run on the same scenario (folders under ``out``), the point's stalls against it."""
    table = []
    for pt in (pt for pt in pts if pt in rows):
        row = {**pt._asdict(), "folder": pt.folder, **rows[pt]}
        reference = next((r for r in rows if r.planner == STALL_REFERENCE and r.scenario == pt.scenario), None)
        if out is not None and reference is not None and pt.samples is not None:
            row["stalls"], row["stall_episodes"] = stalls(episode_speeds(out / pt.folder, pt.episodes),
                                                          episode_speeds(out / reference.folder, reference.episodes))
        table.append(row)
    return table


def plot(figure: str, table: list[dict[str, Any]], path: Path) -> Path:
    """Collision rate (95% interval), speed (sd over collision-free episodes) and median plan time per call against
    the swept value, one line per variant. On a categorical axis (fig7: scenario, fig9: density) each variant's
    markers sit side by side, so overlapping intervals stay readable; plan times spanning more than a factor of 20
    are drawn on a log axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    xlabel = {"fig7": "scenario", "fig8a": "filter iterations", "fig8b": "samples", "fig9": "density [vehicles/km/lane]"}[figure]
    categorical = figure in ("fig7", "fig9")
    categories = list(dict.fromkeys(str(r["x"]) for r in table))
    variants = list(dict.fromkeys(r["variant"] for r in table))
    width = 0.7 / len(variants)
    for i, variant in enumerate(variants):
        rs = [r for r in table if r["variant"] == variant]
        if categorical:
            xs = [categories.index(str(r["x"])) + (i - (len(variants) - 1) / 2) * width for r in rs]
        else:
            xs = [r["x"] for r in rs]
        rate = [r["collision_rate"] for r in rs]
        err = [[r["collision_rate"] - r["collision_ci_low"] for r in rs], [r["collision_ci_high"] - r["collision_rate"] for r in rs]]
        style = {"marker": "o", "capsize": 3, "label": variant, "linestyle": "none" if categorical else "-"}
        axes[0].errorbar(xs, rate, yerr=err, **style)
        axes[1].errorbar(xs, [r["mean_speed_collision_free"] for r in rs], yerr=[r["speed_std_collision_free"] for r in rs],
                         **style)
        axes[2].plot(xs, [r["plan_ms_median"] for r in rs], marker="o", label=variant, linestyle=style["linestyle"])
    for ax, ylabel in zip(axes, ("collision rate", "speed, collision-free [m/s]", "plan time per call, median [ms]")):
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        if categorical:
            ax.set_xticks(range(len(categories)), categories)
            ax.set_xlim(-0.5, len(categories) - 0.5)
    plan_ms = [r["plan_ms_median"] for r in table if r["plan_ms_median"] and math.isfinite(r["plan_ms_median"])]  # idm: none
    if plan_ms and max(plan_ms) > 20 * min(plan_ms):
        axes[2].set_yscale("log")
    axes[0].set_ylim(bottom=0)
    axes[0].legend(fontsize=8)
    episodes = sorted({r["episodes"] for r in table})
    fig.suptitle(f"P2 {figure}: {len(table)} points, {'/'.join(map(str, episodes))} episodes each")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


RECORD_FILES = ("episodes.jsonl", "spec.json")  # what --records keeps of a point's bench folder


def _sync(source: Path, target: Path) -> None:
    target.mkdir(parents=True, exist_ok=True)
    for name in RECORD_FILES:
        if (source / name).exists():
            shutil.copy2(source / name, target / name)


def run(figure: str, out: Path, episodes: int | None, workers: int, weights: dict[str, str | None], duration: float | None,
        planners: list[str] | None = None, records: Path | None = None,
        scenarios: list[str] | None = None, xs: list[str] | None = None) -> list[dict[str, Any]]:
    """Run (or resume) ``figure``'s points under ``out``. ``records``: a folder of kept points (e.g. the repository's
    ``benchmarks/results/p2``); a point missing from ``out`` starts from its records there, and every point's
    records are copied there when it ends or is interrupted, so a new machine resumes where the last one stopped."""
    pts = points(figure, episodes, planners, scenarios, xs)
    specs = {pt: bench_spec(pt, weights, duration) for pt in pts}
    for spec in specs.values():  # every point's names, weights and settings before anything runs
        spec.check()
    rows: dict[Point, dict[str, Any]] = {}
    table: list[dict[str, Any]] = []
    for i, pt in enumerate(pts):
        print(f"[{i + 1}/{len(pts)}] {pt.folder}: {pt.episodes} episodes", flush=True)
        if records is not None and not (out / pt.folder / "episodes.jsonl").exists() and (records / pt.folder).is_dir():
            _sync(records / pt.folder, out / pt.folder)
        try:
            rows[pt] = run_bench(specs[pt], out / pt.folder, workers=workers)[0]
        finally:
            if records is not None and (out / pt.folder).is_dir():
                _sync(out / pt.folder, records / pt.folder)
        table = figure_rows(pts, rows, out)
        write_json(out / f"{figure}.json", table)  # strict JSON, whole or not at all
        plot(figure, table, out / f"{figure}.png")
    return table


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--figure", required=True, choices=["fig7", "fig8a", "fig8b", "fig9"])
    parser.add_argument("--out", required=True, help="folder of the points' bench folders (rerun to resume)")
    parser.add_argument("--episodes", type=int, help="episodes per point (default: the figure's, 30 or 50)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="parallel episodes")
    parser.add_argument("--planners", nargs="+", help="run only these planners' points, in this order (default: all of "
                        "the figure's)")
    parser.add_argument("--scenarios", nargs="+", help="run only the points on these roads (default: all of the figure's)")
    parser.add_argument("--x", nargs="+", help="run only the points at these values of the figure's axis (fig8a: "
                        "iterations, fig8b: samples, fig9: density, fig7: scenario)")
    parser.add_argument("--cvae-weights", help="CVAE checkpoint (default: shipped)")
    parser.add_argument("--vqvae-weights", help="PixelCNN checkpoint (default: shipped)")
    parser.add_argument("--filter-weights", help="learned safety-filter checkpoint (default: shipped)")
    parser.add_argument("--duration", type=float, help="episode length [s] (default: the scenario's)")
    parser.add_argument("--records", help="folder that keeps every point's episodes (benchmarks/results/p2): a point "
                        "missing from --out resumes from there, and is copied back when it ends or is interrupted")
    parser.add_argument("--list", action="store_true", help="print the points and exit")
    args = parser.parse_args(argv)
    stop_cleanly_on_signals()  # SIGTERM, and Ctrl-C under a script's `&`, still copy the points to --records
    try:
        if args.episodes is not None and args.episodes < 1:
            raise DriveoptError(f"--episodes must be at least 1, got {args.episodes}")
        if args.list:
            for pt in points(args.figure, args.episodes, args.planners, args.scenarios, args.x):
                print(f"{pt.folder}: {pt.episodes} episodes ({pt.variant}, x = {pt.x})")
            return 0
        weights = {"cvae": args.cvae_weights, "vqvae": args.vqvae_weights, "filter": args.filter_weights}
        table = run(args.figure, Path(args.out), args.episodes, args.workers, weights, args.duration, args.planners,
                    Path(args.records) if args.records else None, args.scenarios, args.x)
    except DriveoptError as exc:
        print(f"p2_closed_loop: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"p2_closed_loop: interrupted; the finished episodes are kept in {args.out}, rerun the same command to resume",
              file=sys.stderr)
        return 130
    print(f"wrote {args.out}/{args.figure}.json and {args.figure}.png ({len(table)} points)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
