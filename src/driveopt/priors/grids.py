"""Grid priors: the proposal distributions of the MPC baselines of P1 §V (all share the QP, projection and ranking).

- ``VanillaPrior``: no behavioural layer: one sample, speed set-point v_des (approached at a bounded rate), keep
  the current lane.
- ``GridPrior``: a fixed grid of behaviours: constant speed x target lane x when the lane change
  happens (which quarter of the horizon), as many speeds as fill the batch.
- ``GoalGridPrior``: the "Batch-MPC" baseline: a grid of goal positions (x_f, y_f); with
  ``QPConfig(terminal_position=True)`` the planner turns constant speed set-points into
  x_f = x_0 + v T and the last lateral set-point into y_f.

The random-sampling baseline is the Gaussian prior with a single sampler iteration.
Every prior returns exactly ``num`` samples (the grid is tiled to fill the batch).
"""

from __future__ import annotations

import jax.numpy as jnp

from driveopt.config import ProjectionConfig
from driveopt.costs import nearest_lane_center
from driveopt.problem import PlanningProblem
from driveopt.pytree import pytree_dataclass, static
from driveopt.qp import NUM_SEGMENTS, SETPOINT_DIM
from driveopt.sampler import Proposal, clip_setpoints, moments

MAX_LANES = 8  # lanes considered by the grids (masked beyond the road's lane count)
GRID_COVARIANCE_JITTER = 1e-3  # [-] added to the diagonal of a grid's sample covariance


def _fill(rows: jnp.ndarray, valid: jnp.ndarray, num: int) -> jnp.ndarray:
    """``num`` rows cycling through the valid rows of ``rows`` (valid rows first, in order)."""
    order = jnp.argsort(~valid, stable=True)
    count = jnp.maximum(jnp.sum(valid), 1)
    return rows[order[jnp.arange(num) % count]]


def _lane_centres(problem: PlanningProblem) -> tuple[jnp.ndarray, jnp.ndarray]:
    centres = problem.lane_center0 + problem.lane_width * jnp.arange(MAX_LANES, dtype=jnp.float32)
    valid = (jnp.arange(MAX_LANES) < problem.num_lanes) & (centres >= problem.y_lb) & (centres <= problem.y_ub)
    return centres, valid


@pytree_dataclass
class VanillaPrior:
    """Speed set-point v_des, lateral set-point the nearest lane centre; identical samples.

    The row has to be feasible from any state the car is in, or the car keeps choosing its stop row (at rest: for
    the rest of the episode). So the speed set-points approach v_des from the current speed by at most
    ``speed_step`` per quarter of the horizon: the set-point QP follows a step in the set-point at about 0.77 m/s^2
    per m/s (from rest, v_des = 20 m/s in one step peaks at 18.8 m/s^2, a 5 m/s step at 3.8). And the first quarter
    holds the current lateral position: a move to the centre from rest breaks the bounds on the velocity (course and
    curvature)."""

    v_max: float = static(ProjectionConfig.v_max)  # [m/s]
    speed_step: float = static(5.0)  # [m/s] largest change of the speed set-point per quarter of the horizon

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        speed = jnp.hypot(problem.init_x[1], problem.init_y[1])
        reach = self.speed_step * jnp.arange(1, NUM_SEGMENTS + 1, dtype=speed.dtype)
        v = speed + jnp.clip(jnp.minimum(problem.v_des, self.v_max) - speed, -reach, reach)
        y0 = problem.init_y[0]
        y = jnp.where(jnp.arange(NUM_SEGMENTS) == 0, y0, nearest_lane_center(problem, y0))
        p = jnp.broadcast_to(jnp.concatenate([v, y]), (num, SETPOINT_DIM))
        return Proposal(p, p[0], GRID_COVARIANCE_JITTER * jnp.eye(SETPOINT_DIM, dtype=p.dtype))


@pytree_dataclass
class GridPrior:
    """Constant speed x target lane x lane-change quarter, as fine in speed as the batch allows.

    A behaviour is a target lane and the quarter of the horizon (1..4) from which the lateral set-points are that
    lane's centre (before it: the current lateral position). Every behaviour of the road's lanes gets the same
    speeds, evenly spaced on [0, v_max]: as many as fit in the batch (at least 2; rows beyond a whole grid repeat its
    slowest speeds). So the grid uses its whole batch: 250 samples on two lanes give 31 speeds 1 m/s apart. A fixed
    ten-speed grid (3.3 m/s apart) tiled to the batch could not follow a lane flowing at 2 m/s for the 15 s horizon
    and stood still behind it (docs/findings/grid-standstill.md)."""

    v_max: float = static(ProjectionConfig.v_max)  # [m/s]

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        centres, lane_ok = _lane_centres(problem)
        lanes = jnp.argsort(~lane_ok, stable=True)  # the road's lanes first
        behaviours = jnp.maximum(jnp.sum(lane_ok), 1) * NUM_SEGMENTS
        row = jnp.arange(num)
        behaviour = row % behaviours
        num_speeds = jnp.maximum(num // behaviours, 2)
        speed = self.v_max * ((row // behaviours) % num_speeds) / (num_speeds - 1)
        centre = centres[lanes[behaviour // NUM_SEGMENTS]]
        change = behaviour % NUM_SEGMENTS  # 0: the target from the first quarter on
        lateral = jnp.where(jnp.arange(NUM_SEGMENTS)[None, :] < change[:, None], problem.init_y[0], centre[:, None])
        speeds = jnp.broadcast_to(speed.astype(lateral.dtype)[:, None], lateral.shape)
        samples = clip_setpoints(jnp.concatenate([speeds, lateral], axis=-1), problem, self.v_max)
        return Proposal(samples, *moments(samples, GRID_COVARIANCE_JITTER))


@pytree_dataclass
class GoalGridPrior:
    """Goal grid: num_speeds average speeds (x_f = x_0 + v T) x lane centres (y_f)."""

    num_speeds: int = static(25)
    v_max: float = static(ProjectionConfig.v_max)  # [m/s]

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        speeds = jnp.linspace(0.0, self.v_max, self.num_speeds, dtype=jnp.float32)
        centres, lane_ok = _lane_centres(problem)
        v = jnp.broadcast_to(speeds[:, None, None], (self.num_speeds, MAX_LANES, NUM_SEGMENTS))
        y = jnp.broadcast_to(centres[None, :, None], v.shape)
        rows = jnp.concatenate([v, y], axis=-1).reshape(-1, SETPOINT_DIM)
        valid = jnp.broadcast_to(lane_ok[None, :], (self.num_speeds, MAX_LANES)).reshape(-1)
        samples = clip_setpoints(_fill(rows, valid, num), problem, self.v_max)
        return Proposal(samples, *moments(samples, GRID_COVARIANCE_JITTER))
