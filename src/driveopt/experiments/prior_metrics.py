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
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple, Sequence

import jax
import numpy as np

from driveopt.basis import make_basis
from driveopt.config import BasisConfig, PlannerConfig, QPConfig
from driveopt.data.modes import plan_features
from driveopt.errors import DriveoptError
from driveopt.planner import RowKind, plan
from driveopt.problem import PlanningProblem
from driveopt.qp import make_model, qp_layer

BEST_OF = 16  # [-] samples of the coverage metric (the CVAE's)
FEASIBILITY_SAMPLES = 250  # [-] samples of the feasibility and diversity metrics


class MetricError(DriveoptError):
    """Inputs of a metric with the wrong shape or no samples."""


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
