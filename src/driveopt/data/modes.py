"""Multi-modal demonstrations: the distinct feasible plans of the expert's first and final batches (P2 §V-A1).

A CVAE trained on the executed plan alone imitates the expert's pick, not its search
(docs/findings/cvae.md). P2 trains its VQ-VAE on *several* good plans per observation. ``driveopt collect`` stores,
for every planning step, the **modes** of the expert's first and final sampler batches (``PlanResult.first``
and ``PlanResult.last``). Both, because in dense traffic the final batch alone often holds no feasible sample:
the sampler adapts towards the lowest cost + residual, a cheap infeasible plan can draw it there, and the plan it
returns is the best over all iterations (on 600 rows of four-lane-d3.0, 435 had no feasible sample in the final
batch). The first batch is the prior's whole-horizon behaviours around the current state.

1. candidates: rows of either batch that are samples (``RowKind.SAMPLE``: not the previous plan, not the stopping
   rows), feasible (total residual <= ``sampler.residual_tolerance``) and finite;
2. lowest weighted driving cost first (``Snapshot.cost``; ties: lower row index first);
3. a candidate is kept when it is **distinct from every mode already kept**: its target lane differs
   (the lane whose centre is nearest to the plan's lateral position at the horizon, y(T), clipped to
   the road's lanes), or its mean speed over some quarter of the horizon differs by more than
   ``speed_gap`` (:data:`SPEED_GAP`, 2 m/s);
4. at most ``max_modes`` are kept (default :data:`MAX_MODES`, 8); the rest of the M slots are padding
   (zeros, ``mask`` False), valid modes first.

The rule reads the projected plan (what a mode is, and what the VQ-VAE learns to reconstruct), not
its set-points: samples whose set-points differ but that the projection pushes onto the same plan
count once. Everything here is numpy on the host: ``solve`` is untouched.
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np

from driveopt.basis import Basis
from driveopt.planner import RowKind
from driveopt.qp import NUM_SEGMENTS

MAX_MODES = 8  # [-] modes stored per planning step (collect --modes)
SPEED_GAP = 2.0  # [m/s] two plans towards the same lane are distinct when a quarter's mean speed differs by more


class Modes(NamedTuple):
    """Up to M distinct feasible plans of one planning step, lowest cost first, padded (see the module docstring)."""

    setpoints: np.ndarray  # (M, 8) (v_1..v_4 [m/s], y_1..y_4 [m]) of the sample
    coeffs: np.ndarray  # (M, 2n) projected Bernstein coefficients (planning frame: ego at x = 0)
    cost: np.ndarray  # (M,) weighted driving cost of the projected plan
    residual: np.ndarray  # (M,) total constraint residual of the projected plan
    mask: np.ndarray  # (M,) bool: a real mode (False: padding)


def plan_features(coeffs: np.ndarray, basis: Basis, lane_center0: float, lane_width: float,
                  num_lanes: int) -> tuple[np.ndarray, np.ndarray]:
    """(target lane (B,) int, mean speed per quarter (B, 4) [m/s]) of plans with coefficients (B, 2n)."""
    coeffs = np.asarray(coeffs, np.float64)
    n = coeffs.shape[-1] // 2
    c_x, c_y = coeffs[:, :n], coeffs[:, n:]
    y_end = c_y @ basis.W[-1]
    lane = np.clip(np.round((y_end - lane_center0) / lane_width), 0, max(num_lanes - 1, 0)).astype(np.int64)
    speed = np.hypot(c_x @ basis.Wd.T, c_y @ basis.Wd.T)  # (B, K)
    per = speed.shape[1] // NUM_SEGMENTS
    quarters = speed[:, :per * NUM_SEGMENTS].reshape(len(speed), NUM_SEGMENTS, per).mean(axis=-1)
    return lane, quarters


def lanes_per_row(coeffs: np.ndarray, mask: np.ndarray, basis: Basis, lane_center0: np.ndarray, lane_width: np.ndarray,
                  num_lanes: np.ndarray) -> np.ndarray:
    """(n,) how many distinct target lanes the real modes of each of n rows reach (0 for a row without modes).

    coeffs (n, M, 2n_c), mask (n, M) as in :class:`Modes`; the road of each row: lane_center0 [m], lane_width [m],
    num_lanes [-] (n,) each. The target lane is :func:`plan_features`'s."""
    coeffs, mask = np.asarray(coeffs, np.float64), np.asarray(mask, bool)
    counts = np.zeros(len(coeffs), np.int64)
    for i in np.flatnonzero(mask.any(axis=1)):
        lanes, _ = plan_features(coeffs[i][mask[i]], basis, float(lane_center0[i]), float(lane_width[i]), int(num_lanes[i]))
        counts[i] = np.unique(lanes).size
    return counts


def distinct(lane: int, speeds: np.ndarray, kept_lanes: np.ndarray, kept_speeds: np.ndarray, speed_gap: float) -> bool:
    """Whether a plan (target lane, quarter speeds (4,)) differs from every kept one (rule 3 of the module docstring)."""
    if len(kept_lanes) == 0:
        return True
    other_lane = kept_lanes != lane
    other_speed = np.max(np.abs(kept_speeds - speeds), axis=-1) > speed_gap
    return bool(np.all(other_lane | other_speed))


def select_modes(batches: Sequence, problem, basis: Basis, tolerance: float, max_modes: int = MAX_MODES,
                 speed_gap: float = SPEED_GAP) -> Modes:
    """The modes of one planning step (see the module docstring).

    batches: the sampler batches to draw from, (``PlanResult.first``, ``PlanResult.last``) in collect (Snapshots:
    setpoints, projected_coeffs, residual, kind, cost; numpy); rows of earlier batches win cost ties.
    problem: its PlanningProblem (lane_center0, lane_width, num_lanes). basis: the planner's basis.
    tolerance: the expert's ``sampler.residual_tolerance``.
    """
    def rows(field, dtype=np.float32):
        return np.concatenate([np.asarray(getattr(b, field), dtype) for b in batches])

    setpoints, coeffs, residual, cost = rows("setpoints"), rows("projected_coeffs"), rows("residual"), rows("cost")
    kind = rows("kind", np.int64)
    finite = np.isfinite(cost) & np.all(np.isfinite(coeffs), axis=1) & np.all(np.isfinite(setpoints), axis=1)
    ok = (kind == RowKind.SAMPLE) & (residual <= tolerance) & finite
    candidates = np.flatnonzero(ok)
    candidates = candidates[np.argsort(cost[candidates], kind="stable")]
    out = Modes(np.zeros((max_modes, setpoints.shape[1]), np.float32), np.zeros((max_modes, coeffs.shape[1]), np.float32),
                np.zeros(max_modes, np.float32), np.zeros(max_modes, np.float32), np.zeros(max_modes, bool))
    if len(candidates) == 0:
        return out
    lanes, speeds = plan_features(coeffs[candidates], basis, float(problem.lane_center0), float(problem.lane_width),
                                  int(round(float(problem.num_lanes))))
    kept: list[int] = []
    for j in range(len(candidates)):
        if distinct(lanes[j], speeds[j], lanes[kept], speeds[kept], speed_gap):
            kept.append(j)
            if len(kept) == max_modes:
                break
    rows = candidates[kept]
    count = len(rows)
    out.setpoints[:count], out.coeffs[:count] = setpoints[rows], coeffs[rows]
    out.cost[:count], out.residual[:count], out.mask[:count] = cost[rows], residual[rows], True
    return out
