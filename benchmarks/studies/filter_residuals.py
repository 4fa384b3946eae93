"""Offline residuals of P2's learned safety filter against the plain projection, by iteration count.

    python benchmarks/studies/filter_residuals.py --data HELD.h5 [HELD2.h5 ...] --filter-weights filter.ckpt \
        --json out/filter_residuals.json [--samples-from vqvae|cvae|gaussian] [--prior-weights FILE] \
        [--validation 0.1 --seed 0] [--max-rows N] [--samples 250] [--iterations 1 5 10 25 50 100] [--planner vqvae-filter]

Rows: the demonstration rows ``driveopt train filter`` learns from (feasible plan, more than 3 s before
a collision, the trainer's canonical order); with ``--validation F`` only the episodes that training
with the same ``--validation`` and ``--seed`` holds out, otherwise all rows of ``--data`` (a held-out
file); at most ``--max-rows`` evenly spaced ones. Each row's planning problem is rebuilt from its
observation (:mod:`driveopt.data.replay`), as the trainer does.

Planning configuration: ``--planner``'s (default ``vqvae-filter``: barrier projection, gammas 1),
capped at the simulated car's acceleration and curvature as in closed loop
(:func:`driveopt.training.filter.scenario_config`), with ``--samples`` samples (250).

For every row, ``--samples`` set-points are drawn from the prior (``--samples-from``, by default the
one the filter was trained on as its checkpoint records it, else ``vqvae``; ``--prior-weights`` or
the shipped weights; one key per row, ``--seed`` and the row index) and turned into trajectories by
the planner's set-point QP; then, for each k of ``--iterations``, the same trajectories are projected
with ``projection.max_iterations = k`` twice:

* ``learned``: set up by the filter of ``--filter-weights`` (its per-sample gammas, initial
  multipliers and first iterate; :func:`driveopt.planner.project_batch`);
* ``plain``: the projection as configured without a filter (the configuration's fixed gammas, the
  sample as first iterate, zero multipliers).

The projection runs as the planner runs it (not unrolled), so k is "at most k iterations": it stops
earlier once the batch has converged (no coefficient of any sample moved more than
``projection.tolerance``, 1e-3 m, in the last iteration), which leaves its residual where it is; the
iterations actually run are recorded (``iterations``).

Measured per row, variant and k: the median over samples of the total residual of the projected
trajectory against the plain constraints (:func:`driveopt.projection.constraint_residuals`, gamma = 1:
the residual the planner ranks by and eq. 9 trains on; the constraint families summed in their own
units, m, m/s and m/s^2) and the share of samples within the planner's ``sampler.residual_tolerance``
(0.05), over all samples and separately over the lane-changing ones (last lateral set-point more than
half a lane from the ego's y) and the others; and the cost and mean speed of the least-cost feasible
sample, the plan a one-pass pipeline (``vqvae``, ``vqvae-filter``) would choose. Summary per variant and
k: the median over rows of those medians, the mean feasible shares, the pick's mean speed and the mean
iterations run; per variant ``iterations_to_tolerance``, the smallest k of ``--iterations`` at
which the median row's median sample is within the tolerance (null: none).

Output: one JSON line per row in ``<json>.rows.jsonl``, appended as it goes, and the summary (with the
settings and the machine) in ``--json``, rewritten atomically after every row. A rerun of the same
command skips the rows done; a rerun with other settings or data is refused. Bad input (unreadable
data, a corrupted filter checkpoint or one for another road, bad options) is reported on one line
and exits with status 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import os
import platform
import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from driveopt.costs import cost_terms, weighted_cost
from driveopt.data.demonstrations import load_demonstrations
from driveopt.errors import DriveoptError
from driveopt.experiments.rows_file import resume_rows, row_line
from driveopt.files import file_digest, write_json
from driveopt.learned import filter as fl
from driveopt.planner import project_batch, setpoint_batch
from driveopt.projection import constraint_residuals
from driveopt.qp import make_model
from driveopt.registry import get_optimiser
from driveopt.safety.learned import LearnedFilter
from driveopt.training.filter import SAMPLE_SOURCES, draw_setpoints, row_problems, scenario_config, training_prior
from driveopt.training.harness import evaluation_road_rows
from driveopt.trajectory import evaluate

ITERATIONS = (1, 5, 10, 25, 50, 100)  # [-] projection iterations measured by default
SAMPLES = 250  # [-] set-points drawn per row
VARIANTS = ("learned", "plain")


class FilterResidualsError(DriveoptError):
    """Options, data or an existing results file that this run cannot use."""


def machine() -> dict[str, Any]:
    return {"platform": platform.platform(), "cpus": os.cpu_count(), "jax": jax.__version__, "device": str(jax.devices()[0])}


def run_config(config, samples: int, iterations: int):
    """``config`` with ``samples`` per batch, one sampler pass and at most ``iterations`` projection iterations."""
    return config.with_samples(samples).replace(sampler={"num_iterations": 1}, projection={"max_iterations": iterations})


@functools.partial(jax.jit, static_argnames=("config",))
def projected_residuals(problem, setpoints, safety_filter, config):
    """(total plain-constraint residual (S,), iterations run, cost (S,), mean speed (S,) [m/s]) of the set-points (S, 8)
    through the set-point QP and the projection of ``config``, set up by ``safety_filter`` (None: as configured); the
    cost is the planner's ranking cost of the projected trajectory (no previous plan: no consistency term)."""
    model = make_model(config.basis, config.qp)
    qp_coeffs, b_x, b_y = setpoint_batch(model, problem, config, setpoints)
    proj = project_batch(model, problem, config, qp_coeffs, b_x, b_y, safety_filter)
    traj = evaluate(model, proj.coeffs)
    cost = weighted_cost(cost_terms(traj, problem), config.cost)
    residual = constraint_residuals(model, problem, proj.coeffs, config.projection).total
    return residual, proj.iterations, cost, jnp.mean(traj.speed, axis=-1)


def chosen(feasible: np.ndarray, cost: np.ndarray, speed: np.ndarray) -> tuple[float | None, float | None]:
    """(cost, mean speed [m/s]) of the least-cost feasible sample: the one-pass pipeline's pick; (None, None): none."""
    if not feasible.any():
        return None, None
    best = int(np.argmin(np.where(feasible, cost, np.inf)))
    return float(cost[best]), float(speed[best])


def read_rows(path: Path, settings: dict[str, Any]) -> dict[int, dict[str, Any]]:
    """Finished rows of an earlier run with the same settings (:func:`resume_rows`), by row index."""
    def parse(record: dict[str, Any]) -> tuple[int, dict[str, Any]]:
        for variant in VARIANTS:
            for k in settings["iterations"]:
                float(record["results"][variant][str(k)]["residual_median"])
        return int(record["row"]), record

    return dict(resume_rows(path, settings, parse, FilterResidualsError, "filter_residuals"))


def lane_changes(setpoints: np.ndarray, ego_y: float, lane_width: float) -> np.ndarray:
    """(S,) True for the samples whose last lateral set-point [m] lies more than half a lane from the ego's y [m]."""
    return np.abs(setpoints[:, -1] - ego_y) > 0.5 * lane_width


def _share(feasible: np.ndarray) -> float | None:
    return float(np.mean(feasible)) if feasible.size else None


def _mean(values: list[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else None


def summarise(records: list[dict[str, Any]], iterations: list[int], tolerance: float) -> dict[str, Any]:
    """Per variant and k: median over rows of the per-row median residual, mean feasible share, mean iterations run;
    per variant the smallest k whose median is within ``tolerance`` (None: none)."""
    results: dict[str, Any] = {}
    for variant in VARIANTS:
        by_k = {}
        for k in iterations:
            cells = [r["results"][variant][str(k)] for r in records]
            by_k[str(k)] = {"residual_median": float(np.median([c["residual_median"] for c in cells])),
                            "feasible_share": float(np.mean([c["feasible_share"] for c in cells])),
                            "lane_change_feasible_share": _mean([c.get("lane_change_feasible_share") for c in cells]),
                            "keep_lane_feasible_share": _mean([c.get("keep_lane_feasible_share") for c in cells]),
                            "chosen_speed_mean": _mean([c.get("chosen_speed") for c in cells]),
                            "rows_without_feasible": sum(c.get("chosen_speed") is None for c in cells),
                            "iterations_mean": float(np.mean([c["iterations"] for c in cells]))}
        reached = [k for k in iterations if by_k[str(k)]["residual_median"] <= tolerance]
        results[variant] = {"by_iterations": by_k, "iterations_to_tolerance": reached[0] if reached else None}
    return results


def report(settings: dict[str, Any], tolerance: float, done: dict[int, dict[str, Any]]) -> dict[str, Any]:
    records = [done[r] for r in sorted(done)]
    results = summarise(records, settings["iterations"], tolerance) if records else {}
    return {"settings": settings, "machine": machine(), "residual_tolerance": tolerance, "rows": len(records), "results": results}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", nargs="+", required=True, help="demonstrations (HDF5) of one road, from driveopt collect")
    parser.add_argument("--filter-weights", required=True, help="safety-filter checkpoint (driveopt train filter: filter.ckpt)")
    parser.add_argument("--json", default="out/filter_residuals.json", help="summary; per-row results go to <json>.rows.jsonl")
    parser.add_argument("--samples-from", choices=SAMPLE_SOURCES,
                        help="prior the samples come from (default: the one the filter was trained on, else vqvae)")
    parser.add_argument("--prior-weights", help="its checkpoint: pixelcnn.ckpt or cvae.ckpt (default: the weights shipped for the road)")
    parser.add_argument("--planner", default="vqvae-filter", help="optimiser whose projection and tolerance are measured")
    parser.add_argument("--validation", type=float, default=0.0, help="evaluate the episodes train holds out with this fraction")
    parser.add_argument("--seed", type=int, default=0, help="the split's seed (as train's) and the sampling seed")
    parser.add_argument("--max-rows", type=int, default=0, help="evaluate at most this many evenly spaced rows (0: all)")
    parser.add_argument("--samples", type=int, default=SAMPLES, help="set-points drawn per row")
    parser.add_argument("--iterations", type=int, nargs="*", default=list(ITERATIONS), help="projection iteration counts k")
    args = parser.parse_args(argv)
    try:
        return run(args)
    except DriveoptError as exc:
        print(f"filter_residuals: error: {exc}", file=sys.stderr)
        return 2


def check_options(args: argparse.Namespace) -> list[int]:
    """The sorted distinct iteration counts; FilterResidualsError for options out of range."""
    if not args.iterations:
        raise FilterResidualsError("--iterations needs at least one iteration count")
    if min(args.iterations) < 1:
        raise FilterResidualsError(f"--iterations must be positive, got {args.iterations}")
    if not 0.0 <= args.validation < 1.0 or args.seed < 0 or args.max_rows < 0 or args.samples < 1:
        raise FilterResidualsError("--validation must be in [0, 1), --seed and --max-rows >= 0, --samples >= 1")
    return sorted(set(args.iterations))


def notice(message: str) -> None:
    print(f"filter_residuals: {message}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    iterations = check_options(args)
    spec = get_optimiser(args.planner)
    run_config(spec.config, args.samples, iterations[-1])  # ConfigError for too many iterations, before the data is read
    data = load_demonstrations(args.data)
    rows, lanes = evaluation_road_rows(data, args.validation, args.seed, args.max_rows, "a filter is")
    planner, v_des = scenario_config(data, rows, spec.config)
    configs = {k: run_config(planner, args.samples, k) for k in iterations}
    config = configs[iterations[-1]]
    cfg, params, normaliser, meta = fl.load_filter(args.filter_weights, lanes=lanes)
    if cfg.basis != config.basis:
        raise FilterResidualsError(f"the filter's basis {cfg.basis} is not the planner's {config.basis}")
    learned = LearnedFilter(params, normaliser, cfg)
    trained_on = meta.get("prior") if isinstance(meta.get("prior"), dict) else {}
    samples_from = args.samples_from or trained_on.get("samples_from") or "vqvae"
    prior, prior_record = training_prior(samples_from, [lanes], config, args.prior_weights)
    if trained_on and (trained_on.get("samples_from"), trained_on.get("weights")) != (samples_from, prior_record["weights"]):
        notice(f"the filter was trained on samples of another prior ({trained_on}); measuring with {prior_record}")
    if isinstance(meta.get("projection"), dict):
        now = {k: v for k, v in dataclasses.asdict(config.projection).items() if k != "max_iterations"}
        differ = sorted(k for k, v in now.items() if meta["projection"].get(k) != v)
        if differ:
            notice(f"the filter was trained for another projection (differs in {', '.join(differ)})")
    if not config.projection.barrier:
        notice(f"{args.planner}'s projection is not in barrier mode: the filter's gammas are unused, only its initialisation acts")
    tolerance = float(config.sampler.residual_tolerance)

    settings = {"data": data.fingerprint(), "rows": len(rows), "validation": args.validation, "seed": args.seed,
                "max_rows": args.max_rows, "samples": args.samples, "iterations": iterations, "planner": args.planner,
                "filter": file_digest(args.filter_weights), "prior": prior_record}
    summary_path = Path(args.json)
    rows_path = summary_path.with_name(summary_path.stem + ".rows.jsonl")
    summary_path.parent.mkdir(parents=True, exist_ok=True)
    done = read_rows(rows_path, settings)
    base_key = jax.random.PRNGKey(args.seed)
    todo = [int(r) for r in rows if int(r) not in done]
    bar = tqdm(todo, desc="filter residuals", unit="row", initial=len(rows) - len(todo), total=len(rows))
    with rows_path.open("a") as out:
        for row in bar:
            stacked = row_problems(data, np.array([row]), v_des, config)
            key = jax.random.fold_in(base_key, row)
            setpoints = draw_setpoints(prior, jax.tree_util.tree_map(jnp.asarray, stacked), key[None], args.samples)[0]
            problem = jax.tree_util.tree_map(lambda a: jnp.asarray(a[0]), stacked)
            changes = lane_changes(np.asarray(setpoints), float(problem.init_y[0]), float(problem.lane_width))
            results: dict[str, dict[str, Any]] = {variant: {} for variant in VARIANTS}
            for k in iterations:
                for variant, safety_filter in zip(VARIANTS, (learned, None)):
                    residual, ran, cost, speed = projected_residuals(problem, setpoints, safety_filter, configs[k])
                    residual = np.asarray(residual)  # float32, compared with the tolerance as the planner does
                    feasible = residual <= np.float32(tolerance)
                    best_cost, best_speed = chosen(feasible, np.asarray(cost), np.asarray(speed))
                    results[variant][str(k)] = {"residual_median": float(np.median(residual.astype(np.float64))),
                                                "feasible_share": float(np.mean(feasible)),
                                                "lane_change_feasible_share": _share(feasible[changes]),
                                                "keep_lane_feasible_share": _share(feasible[~changes]),
                                                "chosen_cost": best_cost, "chosen_speed": best_speed,
                                                "iterations": int(ran)}
            record = {"row": row, "episode": int(data.episode[row]), "lane_change_share": float(np.mean(changes)),
                      "results": results}
            done[row] = record
            out.write(row_line(record))
            out.flush()
            write_json(summary_path, report(settings, tolerance, done))
            last = str(iterations[-1])
            bar.set_postfix_str(" ".join(f"{v} {results[v][last]['residual_median']:.3f}" for v in VARIANTS))
    final = report(settings, tolerance, done)
    write_json(summary_path, final)
    print(f"{final['rows']} rows, {args.samples} samples each; median over rows of the median sample's residual "
          f"(share of samples within {tolerance:g}):")
    for k in iterations:
        print(f"  k = {k:>4}: " + ", ".join(f"{v} {final['results'][v]['by_iterations'][str(k)]['residual_median']:.4f} "
                                           f"({100 * final['results'][v]['by_iterations'][str(k)]['feasible_share']:.0f}%)"
                                           for v in VARIANTS))
    pct = lambda share: "-" if share is None else f"{100 * share:.0f}%"  # noqa: E731
    print(f"feasible share of the lane-changing samples ({100 * np.mean([r['lane_change_share'] for r in done.values()]):.0f}% of "
          "all: last lateral set-point over half a lane from the ego) / of the others:")
    for k in iterations:
        cells = {v: final["results"][v]["by_iterations"][str(k)] for v in VARIANTS}
        print(f"  k = {k:>4}: " + ", ".join(f"{v} {pct(c['lane_change_feasible_share'])} / {pct(c['keep_lane_feasible_share'])}"
                                           for v, c in cells.items()))
    print("mean speed [m/s] of the least-cost feasible sample (the one-pass pick; rows with none left out):")
    for k in iterations:
        cells = {v: final["results"][v]["by_iterations"][str(k)] for v in VARIANTS}
        print(f"  k = {k:>4}: " + ", ".join(f"{v} {c['chosen_speed_mean']:.2f} ({c['rows_without_feasible']} rows with none)"
                                           if c["chosen_speed_mean"] is not None else f"{v} -" for v, c in cells.items()))
    for v in VARIANTS:
        reached = final["results"][v]["iterations_to_tolerance"]
        print(f"  {v}: median sample within tolerance at k = {reached if reached is not None else 'none of ' + str(iterations)}")
    print(f"wrote {summary_path} and {rows_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
