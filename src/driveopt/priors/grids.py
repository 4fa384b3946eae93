"""Grid priors: the proposal distributions of the MPC baselines of P1 §V (all share the QP, projection and ranking).

- ``VanillaPrior``: no behavioural layer: one sample, speed set-point v_des, keep the current lane.
- ``GridPrior``: a fixed grid of behaviours: constant speed x target lane x when the lane change
  happens (which quarter of the horizon).
- ``GoalGridPrior``: the "Batch-MPC" baseline: a grid of goal positions (x_f, y_f); with
  ``QPConfig(terminal_position=True)`` the planner turns constant speed set-points into
  x_f = x_0 + v T and the last lateral set-point into y_f.

The random-sampling baseline is the Gaussian prior with a single sampler iteration.
Every prior returns exactly ``num`` samples (the grid is tiled to fill the batch).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from driveopt.config import ProjectionConfig
from driveopt.costs import nearest_lane_center
from driveopt.problem import PlanningProblem
from driveopt.qp import NUM_SEGMENTS, SETPOINT_DIM
from driveopt.sampler import Proposal, clip_setpoints, moments

MAX_LANES = 8  # lanes considered by the grids (masked beyond the road's lane count)
GRID_COVARIANCE_JITTER = 1e-3  # [-] added to the diagonal of a grid's sample covariance


def _static(default):
    return dataclasses.field(default=default, metadata=dict(static=True))


def _fill(rows: jnp.ndarray, valid: jnp.ndarray, num: int) -> jnp.ndarray:
    """``num`` rows cycling through the valid rows of ``rows`` (valid rows first, in order)."""
    order = jnp.argsort(~valid, stable=True)
    count = jnp.maximum(jnp.sum(valid), 1)
    return rows[order[jnp.arange(num) % count]]


def _lane_centres(problem: PlanningProblem) -> tuple[jnp.ndarray, jnp.ndarray]:
    centres = problem.lane_center0 + problem.lane_width * jnp.arange(MAX_LANES, dtype=jnp.float32)
    valid = (jnp.arange(MAX_LANES) < problem.num_lanes) & (centres >= problem.y_lb) & (centres <= problem.y_ub)
    return centres, valid


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class VanillaPrior:
    """Speed set-point v_des, lateral set-point the nearest lane centre; identical samples."""

    v_max: float = _static(ProjectionConfig.v_max)  # [m/s]

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        v = jnp.full(NUM_SEGMENTS, jnp.minimum(problem.v_des, self.v_max))
        y = jnp.full(NUM_SEGMENTS, nearest_lane_center(problem, problem.init_y[0]))
        p = jnp.broadcast_to(jnp.concatenate([v, y]), (num, SETPOINT_DIM))
        return Proposal(p, p[0], GRID_COVARIANCE_JITTER * jnp.eye(SETPOINT_DIM, dtype=p.dtype))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class GridPrior:
    """Constant speed (num_speeds values on [0, v_max]) x target lane x lane-change quarter (1..4)."""

    num_speeds: int = _static(10)
    v_max: float = _static(ProjectionConfig.v_max)  # [m/s]

    def rows(self, problem: PlanningProblem) -> tuple[jnp.ndarray, jnp.ndarray]:
        speeds = np.linspace(0.0, self.v_max, self.num_speeds, dtype=np.float32)
        centres, lane_ok = _lane_centres(problem)
        start = problem.init_y[0]
        quarters = np.arange(NUM_SEGMENTS)
        # lateral set-points: current y before the change quarter, the target centre from it on
        lateral = jnp.where(quarters[None, :, None] < quarters[None, None, :], start, centres[:, None, None])
        lateral = jnp.broadcast_to(lateral, (MAX_LANES, NUM_SEGMENTS, NUM_SEGMENTS))  # (lane, change, m)
        v = jnp.broadcast_to(jnp.asarray(speeds)[:, None, None, None], (self.num_speeds, MAX_LANES, NUM_SEGMENTS, NUM_SEGMENTS))
        y = jnp.broadcast_to(lateral[None], v.shape)
        rows = jnp.concatenate([v, y], axis=-1).reshape(-1, SETPOINT_DIM)
        valid = jnp.broadcast_to(lane_ok[None, :, None], (self.num_speeds, MAX_LANES, NUM_SEGMENTS)).reshape(-1)
        return rows, valid

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        rows, valid = self.rows(problem)
        samples = clip_setpoints(_fill(rows, valid, num), problem, self.v_max)
        return Proposal(samples, *moments(samples, GRID_COVARIANCE_JITTER))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class GoalGridPrior:
    """Goal grid: num_speeds average speeds (x_f = x_0 + v T) x lane centres (y_f)."""

    num_speeds: int = _static(25)
    v_max: float = _static(ProjectionConfig.v_max)  # [m/s]

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        speeds = jnp.linspace(0.0, self.v_max, self.num_speeds, dtype=jnp.float32)
        centres, lane_ok = _lane_centres(problem)
        v = jnp.broadcast_to(speeds[:, None, None], (self.num_speeds, MAX_LANES, NUM_SEGMENTS))
        y = jnp.broadcast_to(centres[None, :, None], v.shape)
        rows = jnp.concatenate([v, y], axis=-1).reshape(-1, SETPOINT_DIM)
        valid = jnp.broadcast_to(lane_ok[None, :], (self.num_speeds, MAX_LANES)).reshape(-1)
        samples = clip_setpoints(_fill(rows, valid, num), problem, self.v_max)
        return Proposal(samples, *moments(samples, GRID_COVARIANCE_JITTER))
