"""The proposals of P1's planners as P1's authors' public code draws them (repository ``MPC-Bi-Level``, folder
``expert_mpc/``), for the faithful planners of :mod:`driveopt.faithful`.

- :class:`SpeedOffsetGrid`: MPC-Grid (``expert_grid.py``): 50 speeds on v_des +- 16 m/s x 20 lateral offsets
  across the road, each pair held over the whole horizon (1000 rows).
- :class:`BatchGoals`: Batch-MPC. Its expert is not in ``MPC-Bi-Level`` (``policy_batch.py`` imports
  ``expert_mpc/expert_batch.py``); the same group's ``DiffProj`` publishes it (``compute_projection``): 25 desired
  speeds on v_des +- 12 m/s x 40 terminal lateral positions on [y_lb, y_ub] (1000 goals), each speed tracked over the
  whole horizon, each y_f imposed at its end (with ``QPConfig(terminal_position=True, terminal_longitudinal=False)``).
- :class:`FixedGaussian`: one Gaussian over the eight set-points with a fixed covariance. MPC-Random
  (``policy_random.py``): mean v_des, variance 16 (m/s)^2 per speed, 46 m^2 per lateral offset, the same every call.
  MPC-Bi-Level (``policy_bilevel.py``): variances (30, 30, 30, 30) and (30, 46, 46, 46) around the mean its previous
  call ended with (``self.mean_param``; 5 m/s at the current lateral position before the first call).
- :class:`LearnedStart`: MPC-Bi-Level with the CVAE (``policy_bilevel.py``, ``use_nn``): the CVAE's samples, and for
  the first cross-entropy update the distribution its planner carries between calls (previous final mean, fixed
  start covariance).
- :class:`VanillaGuesses`: MPC-Vanilla (``expert_vanilla.py``): no behavioural layer (P1 §V-A3: p is the desired
  speed), and 1000 guesses of where the projection starts: straight paths at speeds on v_des +- 12 m/s paired with
  smooth random lateral paths around the road's centre, the ones that intrude least into the obstacles' ellipses
  out of 30 times as many.

Every prior returns exactly ``num`` rows; a grid asked for fewer rows than it has keeps evenly spaced ones.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from driveopt.config import BasisConfig, ProjectionConfig
from driveopt.problem import PlanningProblem, ellipse_axes
from driveopt.pytree import pytree_dataclass, static
from driveopt.qp import NUM_SEGMENTS
from driveopt.sampler import Proposal, moments, sample_gaussian, select_lowest

COVARIANCE_JITTER = 1e-3  # [-] added to the diagonal of a proposal's sample covariance
GUESS_NOISE_SCALE = 0.01  # [m^2] expert_vanilla.py: lateral guesses ~ N(centre, 0.01 pinv(R))


def spread_indices(size: int, num: int) -> np.ndarray:
    """``num`` row indices of a table of ``size`` rows: evenly spread when ``num <= size``, cycling otherwise."""
    if num <= size:
        return (np.arange(num) * size) // num
    return np.arange(num) % size


@pytree_dataclass
class SpeedOffsetGrid:
    """``num_speeds`` constant speed set-points on [v_des - speed_spread, v_des + speed_spread] x ``num_offsets``
    constant lateral set-points on [y_lb, y_ub]; speeds below 0 are raised to 0, none is capped at v_max (the
    authors' grid reaches 36 m/s, the projection bounds the speed)."""

    num_speeds: int = static(50)
    num_offsets: int = static(20)
    speed_spread: float = static(16.0)  # [m/s]

    def rows(self, problem: PlanningProblem) -> jnp.ndarray:
        """(num_speeds * num_offsets, 8) set-points, offsets outermost."""
        v = problem.v_des + jnp.linspace(-self.speed_spread, self.speed_spread, self.num_speeds, dtype=jnp.float32)
        y = jnp.linspace(problem.y_lb, problem.y_ub, self.num_offsets).astype(jnp.float32)
        v_grid, y_grid = jnp.meshgrid(jnp.maximum(v, 0.0), y)  # (offsets, speeds)
        v_rows = jnp.repeat(v_grid.reshape(-1, 1), NUM_SEGMENTS, axis=1)
        y_rows = jnp.repeat(y_grid.reshape(-1, 1), NUM_SEGMENTS, axis=1)
        return jnp.concatenate([v_rows, y_rows], axis=1)

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        rows = self.rows(problem)
        samples = rows[spread_indices(rows.shape[0], num)]
        return Proposal(samples, *moments(samples, COVARIANCE_JITTER))


@pytree_dataclass
class BatchGoals:
    """Batch-MPC's goals (``DiffProj`` ``expert_mpc/expert_batch.py``, ``compute_projection``): ``num_speeds``
    desired speeds [m/s] on [v_des - speed_spread, v_des + speed_spread] x ``num_terminal_offsets`` terminal lateral
    positions y_f [m] on [y_lb, y_ub], a full product (25 x 40 = the expert's 1000 rows, terminal positions
    outermost as its ``meshgrid``). A goal becomes set-points: its speed in every quarter, y_f in every quarter; the
    planner imposes y(T) = y_f and tracks the speed (``QPConfig(terminal_position=True, terminal_longitudinal=False)``:
    the expert has no x(T) row) and leaves y untracked before T (``qp.w_lateral = 0``: the expert's y-axis QP has no
    tracking term), so only the last lateral set-point matters. Speeds below 0 are raised to 0 (the expert's never
    are: it plans with v_des = 20 m/s); none is capped at v_max (the projection bounds the speed, as the expert's).

    The expert also initialises its projection from 1000 guessed paths (``compute_traj_guess``, as MPC-Vanilla's:
    :class:`VanillaGuesses`), paired with the goals by row; driveopt's projection starts from its target, so the
    guesses are not carried."""

    num_speeds: int = static(25)  # [-] expert_batch.py: linspace(v_des - v_pert, v_des + v_pert, 25)
    num_terminal_offsets: int = static(40)  # [-] expert_batch.py: linspace(y_lane_lb, y_lane_ub, 40)
    speed_spread: float = static(12.0)  # [m/s] expert_batch.py v_pert

    def rows(self, problem: PlanningProblem) -> jnp.ndarray:
        """(num_speeds * num_terminal_offsets, 8) set-points (v x 4 [m/s], y_f x 4 [m]), terminal positions outermost."""
        return SpeedOffsetGrid(self.num_speeds, self.num_terminal_offsets, self.speed_spread).rows(problem)

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        rows = self.rows(problem)
        samples = rows[spread_indices(rows.shape[0], num)]
        return Proposal(samples, *moments(samples, COVARIANCE_JITTER))


@pytree_dataclass
class FixedGaussian:
    """Independent set-points from one Gaussian: speeds around ``speed_mean`` (None: the problem's v_des) with
    variances ``speed_var``, lateral offsets around the current lateral position with variances ``lateral_var``;
    speeds clipped to [0, v_max], lateral offsets not clipped (as the authors' code). With ``follows_warm_start``
    the warm start (the previous call's final mean, or the current motion before the first call) is the mean
    instead; without, a warm start is ignored."""

    speed_mean: float | None = static(None)  # [m/s]
    speed_var: tuple[float, ...] = static((16.0,) * NUM_SEGMENTS)  # [(m/s)^2] one per quarter
    lateral_var: tuple[float, ...] = static((46.0,) * NUM_SEGMENTS)  # [m^2] one per quarter
    v_max: float = static(ProjectionConfig.v_max)  # [m/s]
    follows_warm_start: bool = static(False)

    def mean(self, problem: PlanningProblem) -> jnp.ndarray:
        speed = problem.v_des if self.speed_mean is None else jnp.float32(self.speed_mean)
        return jnp.concatenate([jnp.full(NUM_SEGMENTS, speed, jnp.float32), jnp.full(NUM_SEGMENTS, problem.init_y[0])])

    def covariance(self) -> jnp.ndarray:
        return jnp.diag(jnp.asarray(self.speed_var + self.lateral_var, jnp.float32))

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        mean = warm_mean if self.follows_warm_start and warm_mean is not None else self.mean(problem)
        cov = self.covariance()
        samples = sample_gaussian(key, mean, cov, num)
        samples = samples.at[:, :NUM_SEGMENTS].set(jnp.clip(samples[:, :NUM_SEGMENTS], 0.0, self.v_max))
        return Proposal(samples, mean, cov)


@pytree_dataclass
class LearnedStart:
    """MPC-Bi-Level's first batch with the CVAE (``policy_bilevel.py``, ``use_nn``): ``learned``'s samples, and as the
    distribution the first cross-entropy update blends the elites into, the one the authors' planner carries
    between calls: the warm start (its previous call's final mean; the current motion before the first call) with
    ``start``'s fixed covariance. (driveopt's ``cvae`` starts the update from the samples' own moments.)"""

    learned: Any  # a prior whose samples make the batch (the CVAE's)
    start: FixedGaussian

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        samples = self.learned.propose(problem, key, num, warm_mean).samples
        mean = self.start.mean(problem) if warm_mean is None else warm_mean
        return Proposal(samples, mean, self.start.covariance())


@functools.lru_cache(maxsize=8)
def lateral_noise_factor(num_nodes: int) -> np.ndarray:
    """(K, K) Cholesky factor of the guesses' lateral covariance 0.01 pinv(R), R = A^T A with A the second
    differences of the K nodes plus rows pinning both ends (expert_vanilla.py): zero at both ends, about 7 m
    standard deviation mid-horizon for K = 100."""
    second = np.diff(np.eye(num_nodes), n=2, axis=0)
    first, last = np.zeros(num_nodes), np.zeros(num_nodes)
    start, end = np.zeros(num_nodes), np.zeros(num_nodes)
    first[0], last[-1] = 1.0, 1.0
    start[:2], end[-2:] = (-2.0, 1.0), (1.0, -2.0)
    a = np.vstack([first, start, second, end, last])
    cov = GUESS_NOISE_SCALE * np.linalg.pinv(a.T @ a)
    return np.linalg.cholesky(0.5 * (cov + cov.T)).astype(np.float32)


@pytree_dataclass
class VanillaGuesses:
    """``oversampling`` x ``num`` guessed paths: a straight longitudinal path at one of ``num_guess_speeds``
    constant speeds on v_des +- ``speed_spread``, paired with a lateral path (the road's centre plus smooth noise,
    :func:`lateral_noise_factor`, clipped to [y_lb, y_ub]); the ``num`` guesses that intrude least into the
    obstacles' ellipses (:meth:`intrusion`) are kept. A kept guess becomes set-points: its speed in every quarter,
    each quarter's mean offset of its lateral path.

    The authors' guesses initialise the projection, whose QP tracks v_des; driveopt's projection starts from its
    target, the set-point QP's trajectory, so a guess enters as the set-points of that target, and the ranking's
    speed cost pulls towards v_des as the authors' QP does."""

    oversampling: int = static(30)  # [-] candidate guesses per kept one (expert_vanilla.py initial_up_sampling)
    num_guess_speeds: int = static(30)  # [-] speeds of the longitudinal guesses (expert_vanilla.py)
    speed_spread: float = static(12.0)  # [m/s] expert_vanilla.py v_pert
    horizon: float = static(BasisConfig.horizon)  # [s] the planner's horizon T
    v_max: float = static(ProjectionConfig.v_max)  # [m/s]

    def candidates(self, problem: PlanningProblem, key: jax.Array, count: int) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
        """(count,) guessed speeds [m/s], (count, K) longitudinal and (count, K) lateral paths [m]."""
        nodes = problem.obstacle_x.shape[1]
        noise = jax.random.normal(key, (count, nodes), jnp.float32) @ jnp.asarray(lateral_noise_factor(nodes)).T
        y = jnp.clip(0.5 * (problem.y_lb + problem.y_ub) + noise, problem.y_lb, problem.y_ub)
        t = jnp.linspace(0.0, self.horizon, nodes, dtype=jnp.float32)
        speeds = problem.v_des + jnp.linspace(-self.speed_spread, self.speed_spread, self.num_guess_speeds, dtype=jnp.float32)
        v = speeds[jnp.arange(count) % self.num_guess_speeds]
        return v, problem.init_x[0] + v[:, None] * t, y

    @staticmethod
    def intrusion(problem: PlanningProblem, x: jnp.ndarray, y: jnp.ndarray) -> jnp.ndarray:
        """(G,) the L2 norm over obstacles and nodes of max(0, 1 - dx^2/a^2 - dy^2/b^2) of paths (x, y) (G, K)."""
        a, b = ellipse_axes(problem)  # (N, K)
        dx = (x[:, None, :] - problem.obstacle_x[None]) / a[None]
        dy = (y[:, None, :] - problem.obstacle_y[None]) / b[None]
        inside = jnp.maximum(0.0, 1.0 - dx**2 - dy**2) * problem.obstacle_mask[None, :, None]
        return jnp.sqrt(jnp.sum(inside**2, axis=(1, 2)))

    def guesses(self, problem: PlanningProblem, key: jax.Array, num: int) -> tuple[jnp.ndarray, jnp.ndarray]:
        """(num,) speeds [m/s] and (num, K) lateral paths [m] of the least intruding of ``oversampling`` x ``num``."""
        v, x, y = self.candidates(problem, key, self.oversampling * num)
        kept = select_lowest(self.intrusion(problem, x, y), num)
        return v[kept], y[kept]

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        v, paths = self.guesses(problem, key, num)
        lateral = paths.reshape(num, NUM_SEGMENTS, -1).mean(axis=2)
        speed = jnp.repeat(jnp.clip(v, 0.0, self.v_max)[:, None], NUM_SEGMENTS, axis=1)
        samples = jnp.concatenate([speed, lateral], axis=1)
        return Proposal(samples, *moments(samples, COVARIANCE_JITTER))
