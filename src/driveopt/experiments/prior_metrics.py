"""Offline metrics of a prior's first batch on held-out demonstrations: coverage, feasibility, diversity.

For one observation (a demonstration row, :func:`driveopt.data.replay.problem_from_row`):

- **best of N** [m^2]: the smallest mean squared node distance between the expert's executed plan and
  the set-point-QP trajectories of N (16) samples: the CVAE's validation metric
  (:func:`driveopt.learned.cvae.prior_coverage`, "held-out best of 16" in docs/results/learned-prior.md) for any prior;
- **feasible samples**: how many of a batch of samples (250) project to a plan within the sampler's
  residual tolerance, through the planner's own projection (one sampler pass of the given
  configuration: ``vqvae``'s is P2's barrier projection, 100 iterations). Where none does, the planner
  can only stop: the pure CVAE start stalls there (docs/findings/cvae.md);
- **distinct lanes**: how many target lanes (the lane centre nearest y(T), as for the expert's modes,
  :func:`driveopt.data.modes.plan_features`) the batch's set-point-QP trajectories reach: 1 for a prior
  that proposes one behaviour, up to the lane count; and the same count among the feasible projected
  plans (the homotopy classes that survive the filter).

Over the rows (:func:`summarise`): the median best of N, the share of rows with at least one feasible
sample, and the median numbers of distinct lanes. The per-row numbers are pure functions of arrays
(:func:`best_of_n`, :func:`feasible_count`, :func:`distinct_lanes`); :func:`row_metrics` runs a prior
and the planner for one row.

Run on held-out demonstrations (:func:`main`)::

    python -m driveopt.experiments.prior_metrics --data HELD.h5 [HELD2.h5 ...] --json out/prior_metrics.json \
        [--cvae-weights FILE] [--vqvae-weights FILE] [--priors gaussian-p1 gaussian cvae vqvae] \
        [--validation 0.1 --seed 0] [--max-rows N] [--samples 250] [--best-of 16] [--planner vqvae]

It measures every usable row (the rows ``driveopt train`` learns from: feasible plan, more than 3 s before a
collision; with ``--validation F`` only the episodes that ``train`` with the same ``--validation`` and ``--seed``
holds out, otherwise all rows of ``--data``, a held-out file) for every prior: best of ``--best-of`` against the
executed expert plan, feasible samples among ``--samples`` through ``--planner``'s projection (default ``vqvae``:
P2's barrier projection, 100 iterations; the configuration capped at the simulated car's acceleration and curvature
as in closed loop) and distinct target lanes. The problem of a row is rebuilt from its observation
(:mod:`driveopt.data.replay`: the 10 neighbours it records, predicted at constant velocity). Every prior sees the
same key per row.

Priors: ``gaussian-p1`` (P1's independent set-points), ``gaussian`` (the ``bilevel`` planner's, half coherent
behaviours) and every learned kind compared offline (:func:`driveopt.learned_kinds.offline_kinds`: ``cvae``,
``vqvae`` (a PixelCNN checkpoint), each with its ``--<kind>-weights`` option); a learned prior without weights
(given, or shipped for the data's lane count) is left out with a notice.

Output: one JSON line per (row, prior) in ``<json>.rows.jsonl``, appended as it goes, and the summary
(:func:`summarise` per prior) in ``--json``, rewritten after every row. A rerun of the same command skips what is
done; a rerun with other settings or data is refused (exit 2, one line ``prior_metrics: error: ...``).
"""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import jax
import numpy as np
from tqdm import tqdm

from driveopt.basis import make_basis
from driveopt.config import BasisConfig, PlannerConfig, QPConfig
from driveopt.data.demonstrations import load_demonstrations
from driveopt.data.modes import plan_features
from driveopt.data.replay import problem_from_row
from driveopt.drivers.optimiser import adapt_to_vehicle
from driveopt.errors import DriveoptError
from driveopt.experiments.rows_file import resume_rows, row_line
from driveopt.files import file_digest, write_json
from driveopt.learned_kinds import offline_kinds
from driveopt.planner import RowKind, plan
from driveopt.problem import PlanningProblem
from driveopt.qp import make_model, qp_layer
from driveopt.registry import get_optimiser
from driveopt.sampler import GaussianPrior
from driveopt.sim.control import BicycleModel
from driveopt.sim.scenarios import get_scenario
from driveopt.training.harness import evaluation_road_rows

BEST_OF = 16  # [-] samples of the coverage metric (the CVAE's)
FEASIBILITY_SAMPLES = 250  # [-] samples of the feasibility and diversity metrics
GAUSSIAN_PRIORS = ("gaussian-p1", "gaussian")  # P1's independent set-points, the bilevel planner's Gaussian


class MetricError(DriveoptError):
    """Inputs of a metric with the wrong shape or no samples."""


class MetricsRunError(DriveoptError):
    """Options, data or an existing results file that a run of :func:`main` cannot use."""


class RowMetrics(NamedTuple):
    """A prior's first batch for one observation."""

    best_of_n: float  # [m^2] smallest mean squared node distance to the expert's plan among N samples
    feasible: int  # [-] samples whose projected plan is within the residual tolerance
    lanes: int  # [-] distinct target lanes of the samples' set-point-QP trajectories
    feasible_lanes: int  # [-] distinct target lanes of the feasible projected plans (0 when none is feasible)


def best_of_n(positions: np.ndarray, expert: np.ndarray) -> float:
    """[m^2] min over samples of the mean over nodes of the squared distance between ``positions`` (S, K, 2) [m] and
    ``expert`` (K, 2) [m] (same frame)."""
    positions, expert = np.asarray(positions, np.float64), np.asarray(expert, np.float64)
    if positions.ndim != 3 or positions.shape[0] == 0 or positions.shape[1:] != expert.shape:
        raise MetricError(f"best_of_n needs positions (S >= 1, K, 2) and an expert plan (K, 2), got {positions.shape} and {expert.shape}")
    return float(np.min(np.mean(np.sum((positions - expert) ** 2, axis=-1), axis=-1)))


def feasible_count(residual: np.ndarray, kind: np.ndarray, tolerance: float) -> int:
    """[-] rows of a batch that are samples (``RowKind.SAMPLE``: not the stop rows or a previous plan) with total
    residual <= ``tolerance``."""
    residual, kind = np.asarray(residual), np.asarray(kind)
    if residual.shape != kind.shape:
        raise MetricError(f"feasible_count: residual {residual.shape} and kind {kind.shape} differ in shape")
    return int(np.sum((kind == RowKind.SAMPLE) & (residual <= tolerance)))


def distinct_lanes(lanes: np.ndarray) -> int:
    """[-] how many different lane indices ``lanes`` (any shape) holds."""
    return int(np.unique(np.asarray(lanes)).size)


def summarise(rows: Sequence[RowMetrics]) -> dict[str, float | int]:
    """Medians (and means) over observations; ``feasible_share`` is the share of rows with >= 1 feasible sample."""
    if not rows:
        raise MetricError("summarise needs at least one row")
    best = np.array([r.best_of_n for r in rows], np.float64)
    feasible = np.array([r.feasible for r in rows], np.float64)
    lanes = np.array([r.lanes for r in rows], np.float64)
    feasible_lanes = np.array([r.feasible_lanes for r in rows], np.float64)
    return {
        "rows": len(rows),
        "best_of_n_median": float(np.median(best)),  # [m^2]
        "best_of_n_mean": float(np.mean(best)),  # [m^2]
        "feasible_share": float(np.mean(feasible > 0)),  # [-]
        "feasible_median": float(np.median(feasible)),  # [-] samples
        "lanes_median": float(np.median(lanes)),  # [-]
        "lanes_mean": float(np.mean(lanes)),  # [-]
        "feasible_lanes_median": float(np.median(feasible_lanes)),  # [-]
    }


@functools.partial(jax.jit, static_argnames=("num", "basis", "qp"))
def proposal_positions(prior: Any, problem: PlanningProblem, key: jax.Array, num: int, basis: BasisConfig, qp: QPConfig):
    """(set-points (num, 8), planning-frame positions (num, K, 2) [m] of their set-point-QP trajectories) of ``num``
    proposals; one compilation per prior type and size."""
    setpoints = prior.propose(problem, key, num, None).samples
    _, positions = qp_layer(make_model(basis, qp), qp, setpoints, problem.init_x, problem.init_y)
    return setpoints, positions


def evaluation_config(config: PlannerConfig, samples: int = FEASIBILITY_SAMPLES) -> PlannerConfig:
    """``config`` with ``samples`` per batch and one sampler pass: the first batch is all the metrics read."""
    return config.with_samples(samples).replace(sampler={"num_iterations": 1})


def row_metrics(prior: Any, problem: PlanningProblem, expert: np.ndarray, config: PlannerConfig, key: jax.Array,
                best_of: int = BEST_OF) -> RowMetrics:
    """The metrics of ``prior`` for one observation: ``expert`` (K, 2) [m] is the executed plan in the planning frame;
    ``config`` (see :func:`evaluation_config`) sets the batch size, the projection and the residual tolerance."""
    k_cover, k_batch = jax.random.split(key)
    _, positions = proposal_positions(prior, problem, k_cover, best_of, config.basis, config.qp)
    first = plan(problem, config, key=k_batch, prior=prior).first
    kind, residual = np.asarray(first.kind), np.asarray(first.residual)
    sampled = kind == RowKind.SAMPLE
    feasible = sampled & (residual <= config.sampler.residual_tolerance)
    road = (float(problem.lane_center0), float(problem.lane_width), int(round(float(problem.num_lanes))))
    basis = make_basis(config.basis)
    lanes, _ = plan_features(np.asarray(first.qp_coeffs)[sampled], basis, *road)
    feasible_lanes = plan_features(np.asarray(first.projected_coeffs)[feasible], basis, *road)[0] if feasible.any() else []
    return RowMetrics(best_of_n(np.asarray(positions), expert), feasible_count(residual, kind, config.sampler.residual_tolerance),
                      distinct_lanes(lanes), distinct_lanes(feasible_lanes))


def prior_names() -> tuple[str, ...]:
    """The priors a run can measure: the Gaussians, then the learned kinds compared offline, in table order."""
    return GAUSSIAN_PRIORS + tuple(kind.name for kind in offline_kinds())


def make_priors(names: Sequence[str], config: PlannerConfig, lanes: int,
                weights: dict[str, str | None]) -> tuple[dict[str, Any], dict[str, str]]:
    """(name -> prior, name -> digest of its weights file) for the priors ``names`` (:func:`prior_names`): a learned
    kind's from ``weights[kind]`` or the weights shipped for ``lanes``, left out with a notice without."""
    learned = {kind.name: kind for kind in offline_kinds()}
    v_max = config.projection.v_max
    gaussian = GaussianPrior.from_config(config.sampler, v_max)
    priors: dict[str, Any] = {}
    digests: dict[str, str] = {}
    for name in names:
        if name == "gaussian-p1":
            priors[name] = GaussianPrior(gaussian.speed_std, gaussian.lateral_std, v_max, 0.0)
        elif name == "gaussian":
            priors[name] = gaussian
        else:
            kind, given = learned[name], weights.get(name)
            path = Path(given) if given else kind.shipped_weights(lanes)
            if path is None:
                print(f"prior_metrics: no {name} weights shipped for {lanes}-lane roads (pass {kind.weights_option}): left out",
                      file=sys.stderr)
                continue
            priors[name] = kind.load_prior(path, v_max, lanes=lanes)
            digests[name] = file_digest(path)
    return priors, digests


def _attribute(option: str) -> str:
    """The attribute argparse stores ``option`` in (``--cvae-weights``: ``cvae_weights``)."""
    return option.lstrip("-").replace("-", "_")


def read_rows(path: Path, settings: dict[str, Any]) -> dict[tuple[str, int], RowMetrics]:
    """Finished (prior, row) results of an earlier run with the same settings (:func:`resume_rows`)."""
    def parse(record: dict[str, Any]) -> tuple[tuple[str, int], RowMetrics]:
        return (record["prior"], record["row"]), RowMetrics(*(record[f] for f in RowMetrics._fields))

    return dict(resume_rows(path, settings, parse, MetricsRunError, "prior_metrics"))


def report(settings: dict[str, Any], priors: list[str], done: dict[tuple[str, int], RowMetrics]) -> dict[str, Any]:
    """The summary file's content: the run's settings and :func:`summarise` of each prior's finished rows."""
    results = {}
    for name in priors:
        rows = [m for (prior, _), m in done.items() if prior == name]
        if rows:
            results[name] = summarise(rows)
    return {"settings": settings, "results": results}


def main(argv: Sequence[str] | None = None) -> int:
    """The command line of the module docstring; 0, or 2 with one line on stderr for unusable options or data."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", nargs="+", required=True, help="demonstrations (HDF5) of one road, from driveopt collect")
    parser.add_argument("--json", default="out/prior_metrics.json", help="summary; per-row results go to <json>.rows.jsonl")
    for kind in offline_kinds():
        parser.add_argument(kind.weights_option, help=f"{kind.checkpoint} (default: the shipped weights for the data's road)")
    parser.add_argument("--priors", nargs="+", choices=prior_names(), default=list(prior_names()))
    parser.add_argument("--planner", default="vqvae", help="optimiser whose projection and tolerance decide feasibility")
    parser.add_argument("--validation", type=float, default=0.0, help="evaluate the episodes train holds out with this fraction")
    parser.add_argument("--seed", type=int, default=0, help="the split's seed (as train's) and the sampling seed")
    parser.add_argument("--max-rows", type=int, default=0, help="evaluate at most this many evenly spaced rows (0: all)")
    parser.add_argument("--samples", type=int, default=FEASIBILITY_SAMPLES)
    parser.add_argument("--best-of", type=int, default=BEST_OF)
    args = parser.parse_args(argv)
    if not 0.0 <= args.validation < 1.0 or args.seed < 0 or args.max_rows < 0 or args.samples < 1 or args.best_of < 1:
        parser.error("--validation must be in [0, 1), --seed and --max-rows >= 0, --samples and --best-of >= 1")
    try:
        return run(args)
    except DriveoptError as exc:
        print(f"prior_metrics: error: {exc}", file=sys.stderr)
        return 2


def run(args: argparse.Namespace) -> int:
    """Measure every row and prior of the parsed options ``args``, resuming the rows file; DriveoptError when unusable."""
    data = load_demonstrations(args.data)
    rows, lanes = evaluation_road_rows(data, args.validation, args.seed, args.max_rows, "the learned priors are")
    spec = get_optimiser(args.planner)
    scenarios = {str(name): get_scenario(str(name)) for name in np.unique(data.episodes["scenario"][data.episode[rows]])}
    configs = {name: evaluation_config(adapt_to_vehicle(spec.config, BicycleModel(acceleration_range=s.acceleration_range, steering_range=s.steering_range)), args.samples) for name, s in scenarios.items()}
    given = {kind.name: getattr(args, _attribute(kind.weights_option)) for kind in offline_kinds()}
    priors, weights = make_priors(args.priors, spec.config, lanes, given)
    settings = {"data": data.fingerprint(), "rows": len(rows), "validation": args.validation, "seed": args.seed,
                "max_rows": args.max_rows, "samples": args.samples, "best_of": args.best_of, "planner": args.planner,
                "priors": list(priors), "weights": weights}
    summary_path = Path(args.json)
    rows_path = summary_path.with_name(summary_path.stem + ".rows.jsonl")
    summary_path.parent.mkdir(parents=True, exist_ok=True)
    done = read_rows(rows_path, settings)
    base_key = jax.random.PRNGKey(args.seed)
    names = list(priors)
    todo = [int(r) for r in rows if any((name, int(r)) not in done for name in names)]
    bar = tqdm(todo, desc="prior metrics", unit="row", initial=len(rows) - len(todo), total=len(rows))
    with rows_path.open("a") as out:
        for row in bar:
            scenario_name = str(data.episodes["scenario"][data.episode[row]])
            config = configs[scenario_name]
            problem = problem_from_row(data, row, scenarios[scenario_name].v_des, config.basis)
            key = jax.random.fold_in(base_key, row)  # the same draws for every prior of a row
            for name in names:
                if (name, row) in done:
                    continue
                metrics = row_metrics(priors[name], problem, data.trajectory[row], config, key, args.best_of)
                done[(name, row)] = metrics
                out.write(row_line({"prior": name, "row": row, **metrics._asdict()}))
                out.flush()
            write_json(summary_path, report(settings, names, done))
            bar.set_postfix_str(" ".join(f"{n}: {100 * s['feasible_share']:.0f}%"
                                         for n, s in report(settings, names, done)["results"].items()))
    final = report(settings, names, done)
    write_json(summary_path, final)
    for name, stats in final["results"].items():
        print(f"{name:>12}: {stats['rows']} rows, best of {args.best_of} {stats['best_of_n_median']:.1f} m^2 (median), "
              f"a feasible sample in {100 * stats['feasible_share']:.0f}% of rows, "
              f"{stats['lanes_median']:.0f} lanes (median; {stats['feasible_lanes_median']:.0f} among feasible plans)")
    print(f"wrote {summary_path} and {rows_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
