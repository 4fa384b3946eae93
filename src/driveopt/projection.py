"""Batch projection of sampled trajectories onto the constraint set (DESIGN §2.3, P1 App. IV, P2 App. VII).

Solves, for every sample j of the batch at once and approximately,

    min 0.5 |xi - xi_bar_j|^2   s.t.  A_eq xi = b_j,  obstacle ellipses, speed, course angle,
                                     acceleration, curvature, centripetal and lane bounds

(the lane, course and obstacle bounds relaxed near t = 0 for a car that starts beyond them, so that it plans its
way back: :func:`lane_bounds`, :func:`course_bounds`, :func:`obstacle_floor`)

by alternating minimisation on an augmented Lagrangian in polar form. Each
iteration is: a linear solve with a KKT matrix that is constant during the call
(inverted once per call, it depends only on which obstacles are present and on
``gamma_lane``); closed-form angles/lengths from normalised vectors (no trig);
slack and multiplier updates. Residuals are Euclidean distances to the feasible
set per constraint family, in physical units: obstacle [m], velocity [m/s],
acceleration [m/s^2], lane [m], each an L2 norm over the nodes, leaving out the values
that A_eq fixes (node 0 is the current state: no plan can change it). The velocity and acceleration rows act at the
nodes, or (``cfg.derivative_bounds``) at the Bernstein control points of the velocity and acceleration on a few pieces
of the horizon: fewer rows, so less arithmetic per iteration, and a speed or acceleration bound met at them holds at
every time (convex hull; conservative). With ``cfg.nearest_obstacles`` a node has only the rows of the obstacles
nearest the targets there (each sample's own nearest, or those nearest any sample: ``cfg.nearest_choice``). With
``cfg.obstacle_stride`` the obstacle rows act at every node over the plan's first seconds and at every few nodes later,
each ellipse grown by how far the ego moves relative to the obstacle over the nodes left out. The residuals are
measured at the nodes, against every obstacle, either way.

Two loop modes share one step function: ``unroll=False`` stops early
(``lax.while_loop``) for planning; ``unroll=True`` runs exactly
``max_iterations`` steps with ``lax.scan`` and is reverse-mode differentiable
(for learning initialisations and barrier parameters, P2 §III-C).
``max_iterations = 0`` projects nothing: the targets come back as they are, with their residuals.

Barrier parameters (``cfg.barrier``): ``gamma_obs`` and ``gamma_lane`` come from the configuration, or
per call (a safety filter, :mod:`driveopt.safety`), either one value for the batch or one per sample.
``gamma_obs`` only moves the lower bound of each obstacle distance ratio; ``gamma_lane`` enters the
lane rows and so the KKT matrix of the y axis: one value shares one inverse for the batch, values
per sample give each sample its own y-axis inverse (B small matrices inverted once per call, by
:func:`quasi_definite_inverse`; each iteration is then a batched matrix-vector product on that axis).
"""

from __future__ import annotations

import enum
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from driveopt import anderson
from driveopt.basis import derivative_control_points
from driveopt.config import ProjectionConfig
from driveopt.problem import PlanningProblem, ellipse_axes, travel_direction
from driveopt.qp import TrajectoryModel, split
from driveopt.scene import CURVATURE_CELL, PATH_SCALE_MIN
from driveopt.xla import float32_products

_EPS = 1e-6
CURVATURE_MIN_SPEED = 1.0  # [m/s] below this speed the curvature bound is not applied

class ProjectionStatus(enum.IntEnum):
    CONVERGED = 0
    MAX_ITERATIONS = 1

    @property
    def message(self) -> str:
        return {
            ProjectionStatus.CONVERGED: "no sample's coefficients moved by more than the tolerance in the last iteration",
            ProjectionStatus.MAX_ITERATIONS: "iteration limit reached before every sample settled",
        }[self]


class Residuals(NamedTuple):
    """Per-sample distances to the feasible set, one array (B,) per constraint family."""

    obstacle: jnp.ndarray  # [m]
    velocity: jnp.ndarray  # [m/s]
    acceleration: jnp.ndarray  # [m/s^2]
    lane: jnp.ndarray  # [m]

    @property
    def total(self) -> jnp.ndarray:
        return self.obstacle + self.velocity + self.acceleration + self.lane


FAMILIES = Residuals._fields


class ProjectionResult(NamedTuple):
    coeffs: jnp.ndarray  # (B, 2n) projected coefficients
    multipliers: jnp.ndarray  # (B, 2n) final lambda (a warm start for the next call)
    residuals: Residuals  # per family, (B,) each
    iterations: jnp.ndarray  # () iterations run
    status: jnp.ndarray  # () ProjectionStatus value
    error: jnp.ndarray  # () max over samples of the coefficient change in the last iteration


class _SampleY(NamedTuple):
    """When every sample has its own ``gamma_lane`` (B samples): each sample's y-axis blocks minus the shared ones
    (built for the configuration's ``gamma_lane``), so a sample whose gamma is the configuration's gets exactly the
    shared numbers."""

    solve: jnp.ndarray  # (B, n, n) coefficient block of each sample's inverse KKT matrix, minus the shared one
    boundary: jnp.ndarray  # (B, n, my) its boundary block, minus the shared one
    penalty_terms: jnp.ndarray  # (2, n, n) its rho F'F minus the shared one is weights[0] terms[0] + weights[1] terms[1]
    penalty_weights: jnp.ndarray  # (2, B, 1)


class _Nearest(NamedTuple):
    """The obstacle slots a sample's rows use at each node when only the nearest k obstacles have rows
    (``cfg.nearest_obstacles``, :func:`_nearest_obstacles`): the fields of :class:`~driveopt.problem.PlanningProblem`
    and :class:`_Operators` that the obstacle rows read, each (k, B, K), slot j holding the j-th nearest obstacle."""

    obstacle_x: jnp.ndarray  # [m]
    obstacle_y: jnp.ndarray  # [m]
    obstacle_a: jnp.ndarray  # [m]
    obstacle_b: jnp.ndarray  # [m]
    obstacle_mask: jnp.ndarray  # 1 for a real obstacle, 0 for padding
    inverse_axes: jnp.ndarray  # (2, k, B, K) [1/m]
    obstacle_floor: jnp.ndarray  # [-]


class _ObstacleNodes(NamedTuple):
    """The obstacle rows' nodes when not every node has them (``cfg.obstacle_stride``, :func:`obstacle_row_nodes`): K_o
    nodes, node 0 the first."""

    forward: jnp.ndarray  # (n, K_o): c -> position at those nodes
    back: jnp.ndarray  # (K_o, n): its transpose, zero where A_eq fixes the position (node 0)
    free: jnp.ndarray  # (K_o,) 0 where A_eq fixes the position
    spread: jnp.ndarray  # (2, K_o) [-] the share of the relative motion to the previous / next of these nodes that a
    # node's ellipse grows by, (g - 1) / (2 g) for a gap of g nodes: the half-gap beyond what a node covers when every
    # node has rows (0 between neighbouring nodes)
    obstacle_steps: tuple | None = None  # ((2, N, K_o), (2, N, K_o)) [m] the obstacles' x and y changes to the previous
    # and next of these nodes (:func:`_steps`), set once per call by :func:`project`


class _Operators(NamedTuple):
    """Per-call constants of the alternating minimisation; axis 0 of stacked arrays is (x, y). The velocity and
    acceleration rows are P each: the K nodes, or the control points (``cfg.derivative_bounds``, :func:`_derivative_operators`)."""

    solve: jnp.ndarray  # (2, n, n) coefficient block of the inverse KKT matrix of each axis
    boundary: tuple[jnp.ndarray, jnp.ndarray]  # (n, mx), (n, my) boundary block of each inverse
    forward: jnp.ndarray  # (n, K + 2P): c -> position at the nodes, velocity and acceleration at their rows
    back: jnp.ndarray  # (K + 2P, n): transpose of ``forward`` without the rows A_eq fixes (the current state is not a constraint)
    free_nodes: tuple  # (K,), (P,), (P,): 0 where position / velocity / acceleration is fixed by A_eq
    penalty: jnp.ndarray  # (2, n, n): rho F'F of each axis
    lane_gamma: jnp.ndarray  # () gamma of the lane rows (1 in plain mode), or (B, 1) one per sample
    lane_rows: jnp.ndarray  # (K,) 1 at the nodes that carry a lane row (all but node 0)
    lane_bounds: jnp.ndarray  # (2, K) upper-row and lower-row bounds e of the row at each node (node 0: unused); (2, B, K) per sample
    course: jnp.ndarray  # (2, P) cosine and sine of the course-angle bound at each velocity row (:func:`course_bounds`)
    curve_recovery: jnp.ndarray  # (2, P) weight of the curve's speed and [m/s] share of the current speed in the speed
    # bound of each velocity row (:func:`recovery_from`)
    acceleration_recovery: jnp.ndarray  # (2, P) weight of a_max and [m/s^2] share of the current acceleration in the
    # bound of each acceleration row (:func:`recovery_from`)
    direction: jnp.ndarray  # () [-] the ego's direction of travel along x: 1 forwards, -1 reversing
    obstacle_floor: jnp.ndarray  # (N, K) lowest ellipse ratio allowed per obstacle and node (:func:`obstacle_floor`)
    inverse_axes: jnp.ndarray  # (2, N, K) [1/m] 1 / the ellipses' longitudinal and lateral semi-axes per node
    per_sample: _SampleY | None  # the y axis's per-sample changes when gamma_lane is per sample, else None
    nearest: _Nearest | None = None  # the obstacles with rows per sample and node when not all of them have rows
    obstacle_nodes: _ObstacleNodes | None = None  # the nodes with obstacle rows when not every node has them

    @property
    def derivative_rows(self) -> int:
        """P: the velocity rows (and the acceleration rows) per axis."""
        return (self.back.shape[0] - self.lane_rows.shape[0]) // 2


class _State(NamedTuple):
    coeffs: jnp.ndarray  # (2, B, n)
    lam: jnp.ndarray  # (2, B, n)
    pull: jnp.ndarray  # (2, B, n) rho F' h for the current (alpha, d)
    d_obs: jnp.ndarray  # (N, B, K) obstacle distance ratios at each node's previous node (1 at node 0), for the barrier
    # bound; (0, B, K) in plain mode
    d_acc: jnp.ndarray  # (B, P) acceleration lengths of the acceleration rows (curvature bound uses them)
    iteration: jnp.ndarray
    error: jnp.ndarray  # () max over samples of the coefficient change of the last step


RECOVERY_REACTION = 0.5  # [s] the widened bounds are held this long beyond the time to stop the lateral motion


def lane_bounds(model: TrajectoryModel, problem: PlanningProblem, cfg: ProjectionConfig) -> tuple[jnp.ndarray, jnp.ndarray]:
    """[m] (lower, upper) bounds of the ego centre at every node (K,): the road's, except near t = 0 when the
    car is outside them or cannot stop its outward lateral motion before them (off-road recovery).

    A bound is widened to the car's reach y0 + vy0^2 / (2 ``a_max``) (outward vy0 only), held until the
    lateral motion can have stopped (vy0 / ``a_max`` +
    :data:`RECOVERY_REACTION`, at most half of ``recovery_time``), then narrowed linearly back to the
    road's bound at ``recovery_time``. A plan that re-enters the road in time counts as feasible, so a
    car that has drifted off keeps planning its way back instead of finding every plan infeasible.
    On the road with no motion that would carry it past a bound, the bounds are the road's.
    """
    t = jnp.asarray(model.t)
    y0, vy0 = problem.init_y[0], problem.init_y[1]
    stop_time = jnp.abs(vy0) / cfg.a_max  # [s] to stop the current lateral motion
    stopping = 0.5 * jnp.abs(vy0) * stop_time  # [m] lateral distance covered meanwhile
    above = jnp.maximum(y0 + jnp.where(vy0 > 0, stopping, 0.0) - problem.y_ub, 0.0)
    below = jnp.maximum(problem.y_lb - y0 + jnp.where(vy0 < 0, stopping, 0.0), 0.0)
    if cfg.recovery_time > 0:
        hold = jnp.minimum(stop_time + RECOVERY_REACTION, 0.5 * cfg.recovery_time)
        fade = jnp.clip((cfg.recovery_time - t) / (cfg.recovery_time - hold), 0.0, 1.0)
    else:
        fade = jnp.zeros_like(t)
    return problem.y_lb - below * fade, problem.y_ub + above * fade


def recovery_weight(t, cfg: ProjectionConfig) -> jnp.ndarray:
    """[-] at the times ``t`` [s]: 1 at t = 0 falling linearly to 0 at ``cfg.recovery_time`` (0 everywhere when it is
    0), how much of a bound's relaxation for a car that starts beyond it remains."""
    return jnp.clip(1.0 - t / cfg.recovery_time, 0.0, 1.0) if cfg.recovery_time > 0 else jnp.zeros_like(t)


def course_bounds(model: TrajectoryModel, problem: PlanningProblem, cfg: ProjectionConfig, t=None) -> jnp.ndarray:
    """[rad] bound on |course angle| (the velocity's angle to the ego's direction of travel along the road,
    :func:`~driveopt.problem.travel_direction`) at every node (K,), or at the times ``t`` [s] given: ``cfg.course_max``,
    except near t = 0 when the car's course already exceeds it: then the bound starts at the current course and
    narrows linearly to ``course_max`` by ``recovery_time`` (as the lane bounds do for a car off the road), so a
    car that is turned across the road plans its way back instead of finding every plan infeasible.

    The bound keeps the projection from turning a blocked plan into a sideways swerve: in dense traffic a plan
    pushed around a stopped car by the obstacle rows alone crossed three lanes in 3 s at 6 m/s (course up to
    0.95 rad), and the lateral speed it built up could not be undone before the next car.

    Below ``cfg.course_min_speed`` the bound is a right angle (:func:`_analysis_step`): a slow plan may move sideways
    but never against the direction of travel, so a plan braked to rest does not roll back."""
    t = jnp.asarray(model.t) if t is None else t
    vx0, vy0 = problem.init_x[1], problem.init_y[1]
    moving = vx0 * vx0 + vy0 * vy0 > CURVATURE_MIN_SPEED ** 2
    course0 = jnp.where(moving, jnp.abs(jnp.arctan2(vy0, travel_direction(problem) * vx0)), 0.0)
    excess = jnp.maximum(course0 - cfg.course_max, 0.0)
    return cfg.course_max + excess * recovery_weight(t, cfg)


def recovery_from(t, current, cfg: ProjectionConfig) -> jnp.ndarray:
    """(2, len(t)) ``(1 - w, w current)`` at the times ``t`` [s], ``w`` (:func:`recovery_weight`) falling from 1 at t = 0
    to 0 at ``recovery_time``: a row's bound ``b`` becomes ``max(b, (1 - w) b + w current)``, so a car already beyond
    the bound is held to it from its ``current`` value down to the bound by ``recovery_time``, as the lane, course and
    obstacle bounds recover. Where ``current`` is within the bound the bound is ``b`` exactly.

    Used for the speed bound from the centripetal bound (``current``: the car's speed [m/s]): a car faster than a
    curve's speed (a curve has come into the preview, or grown sharper) otherwise finds no plan feasible from the first
    row, and the fallback's braking took upstream's racetrack 1.7 m/s below the curve's speed at every sharper curve.
    And, with ``cfg.acceleration_recovery``, for the acceleration bound (``current``: the car's acceleration's
    magnitude [m/s^2]): every plan starts at the car's acceleration, braking at the car's limit on a bend puts it above
    ``a_max`` (capped at the same limit in closed loop), and without it every plan's first rows were infeasible until
    the car had slowed (upstream's lane-keeping-v0: from 17.9 to 4.5 m/s)."""
    weight = recovery_weight(t, cfg)
    return jnp.stack([1.0 - weight, weight * current])


def obstacle_floor(model: TrajectoryModel, problem: PlanningProblem, cfg: ProjectionConfig) -> jnp.ndarray:
    """[-] (N, K) lowest ellipse ratio each obstacle's constraint allows at each node: 1 (outside the ellipse), except
    for an obstacle whose ellipse already holds the ego at t = 0, at ratio r0 < 1: then r0, rising linearly to 1 by
    ``recovery_time`` (as the lane and course bounds recover).

    The ellipses circumscribe the two cars' boxes with margins, so a car can be inside one without touching: stopped
    in a jam beside a stopped car, or cut in on. No plan can leave at once, so without the floor every plan stays
    infeasible and the car stops where it is, however the traffic around it moves. With it, plans that move away in
    time are feasible, and those that go deeper into the ellipse are not."""
    t = jnp.asarray(model.t)
    a, b = ellipse_axes(problem)
    dx = (problem.init_x[0] - problem.obstacle_x[:, 0]) / a[:, 0]
    dy = (problem.init_y[0] - problem.obstacle_y[:, 0]) / b[:, 0]
    r0 = jnp.minimum(jnp.sqrt(dx * dx + dy * dy), 1.0)[:, None]
    fade = jnp.clip(t / cfg.recovery_time, 0.0, 1.0) if cfg.recovery_time > 0 else jnp.ones_like(t)
    return r0 + (1.0 - r0) * fade


def lane_constraint(model: TrajectoryModel, lower, upper, gamma_lane, barrier: bool) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Lane rows G (2(K-1), n) and bounds e with G c_y <= e, on nodes 1..K-1 (node 0 is fixed by A_eq).

    lower, upper: [m] bounds of y per node (K,) (:func:`lane_bounds`), or scalars.
    Plain: y[k] <= upper[k], -y[k] <= -lower[k]. Barrier (P2 eq. 16-19):
    y[k+1] - upper[k+1] <= (1 - g)(y[k] - upper[k]) and its mirror; g = 1 recovers the plain rows.
    gamma_lane: a number, or (B, 1) one per sample: then G is (B, 2(K-1), n) and e (B, 2(K-1)).
    """
    g = gamma_lane if barrier else 1.0
    W = jnp.asarray(model.W)
    K = W.shape[0]
    upper, lower = (jnp.broadcast_to(b, (K,)) for b in (upper, lower))
    if jnp.ndim(g) == 2:  # (B, 1): one set of rows per sample
        c = 1.0 - g
        rows = W[1:] - c[:, :, None] * W[:-1]
        return (jnp.concatenate([rows, -rows], axis=1),
                jnp.concatenate([upper[1:] - c * upper[:-1], -(lower[1:] - c * lower[:-1])], axis=1))
    rows = W[1:] - (1.0 - g) * W[:-1]
    return (
        jnp.concatenate([rows, -rows]),
        jnp.concatenate([upper[1:] - (1.0 - g) * upper[:-1], -(lower[1:] - (1.0 - g) * lower[:-1])]),
    )


def _kkt_matrix(hessian: jnp.ndarray, A) -> jnp.ndarray:
    """[[H, A'], [A, 0]] for a Hessian (n, n) or a batch of them (B, n, n) and equality rows A (m, n)."""
    batch = hessian.shape[:-2]
    A = jnp.broadcast_to(jnp.asarray(A, hessian.dtype), batch + jnp.shape(A))
    zeros = jnp.zeros(batch + (A.shape[-2],) * 2, hessian.dtype)
    return jnp.concatenate([jnp.concatenate([hessian, jnp.swapaxes(A, -1, -2)], -1), jnp.concatenate([A, zeros], -1)], -2)


def quasi_definite_inverse(matrices: jnp.ndarray) -> jnp.ndarray:
    """Inverses of a batch (B, m, m) of quasi-definite matrices [[H, A'], [A, 0]] (H symmetric positive definite, A of
    full row rank), by Gauss-Jordan elimination without pivoting: every leading block of such a matrix is invertible,
    so no pivot is zero. The batch runs on the last axis, so each elimination step is one vectorised pass over all
    matrices; for the planner's 1000 matrices of 14 x 14 this is ~3x faster than ``jnp.linalg.inv`` (LU with pivoting,
    one small matrix at a time)."""
    m = matrices.shape[-1]
    a = jnp.moveaxis(matrices, 0, -1)  # (m, m, B)
    inverse = jnp.broadcast_to(jnp.eye(m, dtype=a.dtype)[:, :, None], a.shape)
    for i in range(m):  # static: m is the basis size plus the equality rows
        pivot_row, inverse_row = a[i] / a[i, i], inverse[i] / a[i, i]  # (m, B)
        column = a[:, i][:, None]  # (m, 1, B)
        a = (a - column * pivot_row[None]).at[i].set(pivot_row)
        inverse = (inverse - column * inverse_row[None]).at[i].set(inverse_row)
    return jnp.moveaxis(inverse, -1, 0)


_inverse = jax.custom_batching.custom_vmap(jnp.linalg.inv)  # vmap calls the rule below only with the matrix batched
_inverse.def_vmap(lambda axis_size, in_batched, matrices: (quasi_definite_inverse(matrices), True))


@jax.custom_vjp
def kkt_inverse(matrix: jnp.ndarray) -> jnp.ndarray:
    """The inverse of one quasi-definite matrix (m, m) (:func:`quasi_definite_inverse`): LAPACK's LU as a planning
    call computes it, and, where a transformation batches it (a loss vmapped over training rows), the vectorised
    elimination of :func:`quasi_definite_inverse`. A batched LU on the CPU splits its triangular solves over XLA's
    intra-op thread pool from inside that pool; two of them at once on a 2-thread pool each wait for work that no free
    thread can run, and training stops for good (seen with the x and y inverses of a vmapped loss)."""
    return _inverse(matrix)


def _kkt_inverse_forward(matrix):
    inverse = _inverse(matrix)
    return inverse, inverse


def _kkt_inverse_backward(inverse, cotangent):
    transposed = jnp.swapaxes(inverse, -1, -2)
    return (-(transposed @ cotangent @ transposed),)  # d(M^-1) = -M^-1 dM M^-1


kkt_inverse.defvjp(_kkt_inverse_forward, _kkt_inverse_backward)


def _shift_right(a):
    """a[:, k-1] at k, 0 at k = 0."""
    return jnp.concatenate([jnp.zeros_like(a[:, :1]), a[:, :-1]], axis=1)


def _previous_node(ratios):
    """(N, B, K) obstacle ratios -> each node's previous node's ratio, 1 at node 0 (the barrier's lower bound there
    is the plain one)."""
    return jnp.concatenate([jnp.ones_like(ratios[..., :1]), ratios[..., :-1]], axis=-1)


def _shift_left(a):
    """a[:, k+1] at k, 0 at k = K-1."""
    return jnp.concatenate([a[:, 1:], jnp.zeros_like(a[:, :1])], axis=1)


def _derivative_operators(model: TrajectoryModel, problem: PlanningProblem, cfg: ProjectionConfig, where: str) -> dict:
    """The fields ``forward``, ``back``, ``free_nodes``, ``course``, ``curve_recovery`` and ``acceleration_recovery`` of
    :class:`_Operators` with the velocity and acceleration rows at the K nodes (``where`` "nodes"), or at the control
    points of the velocity and of the acceleration on ``cfg.derivative_pieces`` pieces of the horizon (``where`` "control_points",
    :func:`~driveopt.basis.derivative_control_points`). A control point stands for the time of its abscissa (the course
    bound is taken there); the first is the value at t = 0, fixed where node 0's is."""
    W = jnp.asarray(model.W)
    free = jnp.asarray(model.free_nodes)
    if where == "nodes":
        Wd, Wdd, free_v, free_a = jnp.asarray(model.Wd), jnp.asarray(model.Wdd), free[1], free[2]
        t = jnp.asarray(model.t)
    else:
        horizon = jnp.asarray(model.t)[-1]
        velocity, acceleration = (jnp.asarray(a, W.dtype)
                                  for a in derivative_control_points(W.shape[1] - 1, 1.0, cfg.derivative_pieces))
        Wd, Wdd = velocity / horizon, acceleration / (horizon * horizon)
        first = jnp.arange(Wd.shape[0]) == 0
        free_v, free_a = jnp.where(first, free[1, 0], 1.0), jnp.where(first, free[2, 0], 1.0)
        t = jnp.linspace(0.0, 1.0, Wd.shape[0]) * horizon
    course = course_bounds(model, problem, cfg, t)
    # Values fixed by A_eq (the current state at node 0) are not constraint rows: no plan can change them.
    free = (free[0], free_v, free_a)
    return dict(forward=jnp.concatenate([W, Wd, Wdd]).T,
                back=jnp.concatenate([a * f[:, None] for a, f in zip((W, Wd, Wdd), free)]), free_nodes=free,
                course=jnp.stack([jnp.cos(course), jnp.sin(course)]),
                curve_recovery=recovery_from(t, jnp.hypot(problem.init_x[1], problem.init_y[1]), cfg),
                acceleration_recovery=recovery_from(t, jnp.hypot(problem.init_x[2], problem.init_y[2]), cfg))


def obstacle_row_nodes(t, cfg: ProjectionConfig) -> np.ndarray:
    """Indices of the nodes (times ``t`` (K,) [s]) that carry obstacle rows: every node up to
    ``cfg.obstacle_dense_time``, then every ``cfg.obstacle_stride``-th, and the last."""
    t = np.asarray(t)
    K = t.shape[0]
    if cfg.obstacle_stride == 1:
        return np.arange(K)
    last_dense = max(int(np.searchsorted(t, cfg.obstacle_dense_time * (1 + 1e-6), side="right")) - 1, 0)
    nodes = np.concatenate([np.arange(last_dense + 1), np.arange(last_dense + cfg.obstacle_stride, K, cfg.obstacle_stride)])
    return nodes if nodes[-1] == K - 1 else np.append(nodes, K - 1)


def _obstacle_nodes(W: jnp.ndarray, free: jnp.ndarray, nodes: np.ndarray) -> _ObstacleNodes:
    """The rows' operators at ``nodes`` (:func:`obstacle_row_nodes`) from the basis ``W`` (K, n) and the position's free
    flags ``free`` (K,), with each node's share of the motion over the gaps beside it."""
    gaps = np.diff(nodes).astype(np.float64)
    before, after = np.concatenate([[1.0], gaps]), np.concatenate([gaps, [1.0]])
    spread = np.stack([(before - 1.0) / (2.0 * before), (after - 1.0) / (2.0 * after)])
    return _ObstacleNodes(W[nodes].T, W[nodes] * free[nodes, None], free[nodes], jnp.asarray(spread, W.dtype))


def _operators(model: TrajectoryModel, problem: PlanningProblem, cfg: ProjectionConfig, gamma_lane) -> _Operators:
    """gamma_lane: a number, or (B, 1) one per sample (barrier mode only; see the module docstring and :class:`_SampleY`)."""
    n_active = jnp.sum(problem.obstacle_mask)
    if 0 < cfg.nearest_obstacles < problem.obstacle_x.shape[0]:  # k rows per node (fewer where fewer obstacles are real)
        n_active = jnp.minimum(n_active, cfg.nearest_obstacles)
    W = jnp.asarray(model.W)
    rows = _derivative_operators(model, problem, cfg, cfg.derivative_bounds)
    per_sample = cfg.barrier and jnp.ndim(gamma_lane) == 2
    shared_gamma = cfg.gamma_lane if per_sample else gamma_lane
    G, e = lane_constraint(model, *lane_bounds(model, problem, cfg), shared_gamma, cfg.barrier)
    K, P = W.shape[0], rows["course"].shape[1]
    Wm, Wdm, Wddm = rows["back"][:K], rows["back"][K:K + P], rows["back"][K + P:]
    sparse = None
    if cfg.obstacle_stride > 1:
        sparse = _obstacle_nodes(W, rows["free_nodes"][0], obstacle_row_nodes(model.t, cfg))
    Wo = Wm if sparse is None else sparse.back
    penalty_x = (
        cfg.rho_obstacle * n_active * Wo.T @ Wo + cfg.rho_velocity * Wdm.T @ Wdm + cfg.rho_acceleration * Wddm.T @ Wddm
    )
    penalty_y = penalty_x + cfg.rho_lane * G.T @ G
    n = W.shape[1]
    eye = jnp.eye(n, dtype=W.dtype)

    inv_x = kkt_inverse(_kkt_matrix(eye + penalty_x, model.A_x))
    inv_y = kkt_inverse(_kkt_matrix(eye + penalty_y, model.A_y))
    bounds = jnp.pad(e.reshape(2, -1), ((0, 0), (1, 0)))  # per node; node 0 has no row
    sample_y = None
    if per_sample:
        # G'G of the rows W[1:] - c W[:-1] (upper and lower: twice) is quadratic in c = 1 - gamma; its change from the
        # shared gamma is exactly zero for a sample with that gamma.
        c, c_shared = 1.0 - gamma_lane, 1.0 - cfg.gamma_lane  # (B, 1), ()
        cross = W[1:].T @ W[:-1]
        terms = jnp.stack([W[:-1].T @ W[:-1], -(cross + cross.T)])
        weights = 2.0 * cfg.rho_lane * jnp.stack([c * c - c_shared * c_shared, c - c_shared])  # (2, B, 1)
        change = jnp.einsum("wb,wnm->bnm", weights[:, :, 0], terms)  # (B, n, n)
        inverses = quasi_definite_inverse(_kkt_matrix(eye + penalty_y + change, model.A_y))  # (B, n + my, n + my)
        # A sample with the shared gamma has no change at all (its rounding in the other inversion is not one).
        unchanged = (c == c_shared)[:, :, None]
        sample_y = _SampleY(jnp.where(unchanged, 0.0, inverses[:, :n, :n] - inv_y[:n, :n]),
                            jnp.where(unchanged, 0.0, inverses[:, :n, n:] - inv_y[:n, n:]), terms, weights)
        e_samples = lane_constraint(model, *lane_bounds(model, problem, cfg), gamma_lane, cfg.barrier)[1]  # (B, 2(K-1))
        bounds = jnp.pad(jnp.swapaxes(e_samples.reshape(e_samples.shape[0], 2, -1), 0, 1), ((0, 0), (0, 0), (1, 0)))
    return _Operators(
        solve=jnp.stack([inv_x[:n, :n], inv_y[:n, :n]]),
        boundary=(inv_x[:n, n:], inv_y[:n, n:]),
        **rows,
        penalty=jnp.stack([penalty_x, penalty_y]),
        lane_gamma=jnp.asarray(gamma_lane if cfg.barrier else 1.0, W.dtype),
        lane_rows=(jnp.arange(W.shape[0]) > 0).astype(W.dtype),
        lane_bounds=bounds,  # (2, K), or (2, B, K) per sample
        direction=travel_direction(problem),
        obstacle_floor=obstacle_floor(model, problem, cfg),
        inverse_axes=1.0 / jnp.stack(ellipse_axes(problem)),
        per_sample=sample_y,
        obstacle_nodes=sparse,
    )


def _at_nodes(ops: _Operators, model: TrajectoryModel, problem: PlanningProblem, cfg: ProjectionConfig) -> _Operators:
    """``ops`` with its velocity, acceleration and obstacle rows at every node, to measure residuals where the plain
    rows act."""
    if cfg.derivative_bounds != "nodes":
        ops = ops._replace(**_derivative_operators(model, problem, cfg, "nodes"))
    return ops._replace(obstacle_nodes=None)


def _per_node(values: jnp.ndarray, K: int) -> jnp.ndarray:
    """An obstacle field (N,) or (N, K) as (N, K): one value per obstacle and node."""
    return jnp.broadcast_to(values[:, None] if values.ndim == 1 else values, (values.shape[0], K))


def _target_ratios(model: TrajectoryModel, problem: PlanningProblem, target: jnp.ndarray) -> jnp.ndarray:
    """(N, B, K) squared ellipse ratio of every obstacle at each node of each sample's target trajectory (2, B, n);
    infinite for padding, so real obstacles rank first."""
    W = jnp.asarray(model.W)
    x, y = target[0] @ W.T, target[1] @ W.T  # (B, K) [m]
    a, b = ellipse_axes(problem)  # (N, K)
    ratio = ((x - problem.obstacle_x[:, None]) / a[:, None]) ** 2 + ((y - problem.obstacle_y[:, None]) / b[:, None]) ** 2
    return jnp.where(problem.obstacle_mask[:, None, None] > 0, ratio, jnp.inf)


def _nearest_obstacles(problem: PlanningProblem, ratio: jnp.ndarray, k: int, floor: jnp.ndarray) -> _Nearest:
    """The k obstacles nearest each sample's target trajectory at each node (``ratio``, :func:`_target_ratios`), with
    their lowest allowed ratios ``floor`` (N, K), chosen once per projection: the rows stay the same during the call, so
    its KKT matrix (k obstacle rows per node) and its fixed-point map do not change."""
    a, b = ellipse_axes(problem)  # (N, K)
    K = a.shape[1]
    slots = jnp.moveaxis(jax.lax.top_k(-jnp.moveaxis(ratio, 0, -1), k)[1], -1, 0)  # (k, B, K) obstacle indices

    def gather(values):  # (N,) or (N, K) -> (k, B, K)
        return _per_node(values, K)[slots, jnp.arange(K)]

    return _Nearest(*(gather(v) for v in (problem.obstacle_x, problem.obstacle_y, problem.obstacle_a, problem.obstacle_b,
                                          problem.obstacle_mask)),
                    1.0 / jnp.stack([gather(a), gather(b)]), gather(floor))


def _nearest_for_batch(problem: PlanningProblem, ops: _Operators, ratio: jnp.ndarray,
                       k: int) -> tuple[PlanningProblem, _Operators]:
    """(problem, ops) with, at each node, only the k obstacles that come nearest to any sample's target trajectory
    there (``ratio``, :func:`_target_ratios`): their per-node fields (k, K) in place of the N obstacles', so the rows
    read them as the plain rows read every obstacle's."""
    K = problem.obstacle_x.shape[1]
    slots = jax.lax.top_k(-jnp.min(ratio, axis=1).T, k)[1].T  # (k, K) obstacle indices, nearest first

    def gather(values):  # (N,) or (N, K) -> (k, K)
        return jnp.take_along_axis(_per_node(values, K), slots, 0)

    rows_problem = problem._replace(**{name: gather(getattr(problem, name)) for name in
                                       ("obstacle_x", "obstacle_y", "obstacle_a", "obstacle_b", "obstacle_mask")})
    return rows_problem, ops._replace(obstacle_floor=gather(ops.obstacle_floor),
                                      inverse_axes=jnp.stack([gather(axes) for axes in ops.inverse_axes]))


def _safe_sqrt(x):
    """sqrt with a finite gradient at 0 (values below 1e-12 read as 0)."""
    positive = x > 1e-12
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


@jax.custom_jvp
def _fast_rsqrt(x):
    """1/sqrt(x) for x in [1e-30, 1e30] (clipped to it) to 5e-6 relative, from the exponent-halving bit trick
    and two Newton steps.

    Only cheap ops (no sqrt, no divide), so XLA fuses it into each consumer instead of materialising it:
    the ten obstacle terms of an iteration become two fused loops instead of twelve kernels. With
    512-bit vectors (``XLA_CPU_COMPILER_OPTIONS``) this is ~15% of a planning call (DESIGN §6)."""
    x = jnp.clip(x, 1e-30, 1e30)
    bits = jax.lax.bitcast_convert_type(x, jnp.int32)
    y = jax.lax.bitcast_convert_type(jnp.int32(0x5F375A86) - (bits >> 1), x.dtype)
    for _ in range(2):
        y = y * (1.5 - 0.5 * x * y * y)
    return y


@_fast_rsqrt.defjvp
def _fast_rsqrt_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    y = _fast_rsqrt(x)
    return y, -0.5 * y * y * y * dx


def _fast_sqrt(x):
    """sqrt(x) for x >= 0 from :func:`_fast_rsqrt` (cheap ops only), 0 (with a zero gradient) below 1e-12."""
    positive = x > 1e-12
    return jnp.where(positive, x * _fast_rsqrt(jnp.where(positive, x, 1.0)), 0.0)


def _pair(x, y, one):
    """x and y as they are, computed in one loop. XLA's CPU fusion gives each array that a product consumes a loop
    of its own, so the x and y parts of a pull, built from the same terms (ten neighbours' scale factors, the
    velocity's bounds), would compute those terms twice. Packed as one complex array and divided by ``one`` (1 + 0i
    computed at run time, so XLA cannot fold it), they come from one loop: XLA does not duplicate an expensive
    operation such as the division into its two consumers, so the packed array is computed once and both parts are
    read from it. Exact for finite x and y (an infinite part would make the other NaN); every pair here is bounded."""
    packed = jax.lax.complex(x, y) / one
    return jnp.real(packed), jnp.imag(packed)


def road_curvature_at(cells: jnp.ndarray, x: jnp.ndarray) -> jnp.ndarray:
    """[1/m] the road's signed curvature at positions ``x`` [m] (any shape): the value of the CURVATURE_CELL-long cell
    of ``cells`` (C,) each lies in, the first cell for positions behind x = 0 and the last beyond the table."""
    index = jnp.clip(jnp.floor(x * (1.0 / CURVATURE_CELL)), 0, cells.shape[0] - 1).astype(jnp.int32)
    return cells[index]


def _row_nodes(rows: int, nodes: int) -> np.ndarray:
    """Index of the node nearest in time to each of ``rows`` velocity rows spread evenly over the horizon (the control
    points stand for the times of their abscissae)."""
    return np.rint(np.linspace(0.0, nodes - 1, rows)).astype(int)


def _normalise(ux, uy):
    """Length and unit direction of (ux, uy); direction (1, 0) where the length vanishes."""
    sq = ux * ux + uy * uy
    inv = _fast_rsqrt(jnp.maximum(sq, _EPS * _EPS))
    tiny = sq <= _EPS * _EPS
    return sq * inv, jnp.where(tiny, 1.0, ux * inv), jnp.where(tiny, 0.0, uy * inv)


def _analysis_step(
    coeffs, d_obs_prev, d_acc_prev, ops: _Operators, problem: PlanningProblem, cfg: ProjectionConfig, gamma_obs,
    with_residuals: bool = True, aggregate_obstacles: bool = False,
):
    """Closed-form (alpha, d), slack, rho F'h (and residuals) for the trajectories ``coeffs`` (2, B, n).

    aggregate_obstacles: the obstacle residual from the sum of the obstacles' displacements sum_i (p - h_i) at each node
    (what the pull holds anyway) instead of each obstacle's own: the same where at most one obstacle binds at a node,
    and about half the cost of an iteration less (XLA computes each obstacle's terms again for a per-obstacle sum)."""
    K, P = ops.lane_rows.shape[0], ops.derivative_rows
    nodes = coeffs @ ops.forward  # (2, B, K + 2P)
    x, vx, ax = nodes[0, :, :K], nodes[0, :, K:K + P], nodes[0, :, K + P:]
    y, vy, ay = nodes[1, :, :K], nodes[1, :, K:K + P], nodes[1, :, K + P:]

    # Obstacles: x - x_o = a d cos(alpha), y - y_o = b d sin(alpha), d >= lower bound. For the pulls, a static loop
    # over obstacles of (B, K) slices fuses far better on CPU than (B, N, K) arrays reduced over N; the barrier's
    # ratios, a state, are one (N, B, K) array, computed in one loop instead of one per obstacle and a stacking copy.
    # With ``cfg.nearest_obstacles`` the rows are those of each sample's nearest obstacles per node (slots of (B, K)
    # arrays in place of the problem's (K,) rows; the same arithmetic).
    # With ``ops.obstacle_nodes`` the rows act at those nodes only (``problem`` holds the obstacles' values there).
    obstacles = problem if ops.nearest is None else ops.nearest
    sparse = ops.obstacle_nodes
    ox, oy = (x, y) if sparse is None else coeffs @ sparse.forward  # (B, K_o) [m] the ego at the obstacle rows' nodes
    if sparse is not None:  # the ego's moves between those nodes, once for every obstacle
        ego_steps = (_steps(ox), _steps(oy))  # (2, B, K_o) each
        obstacle_steps = sparse.obstacle_steps
    h_ox = jnp.zeros_like(ox)
    h_oy = jnp.zeros_like(oy)
    obstacle_sq = jnp.zeros_like(ox)
    inv_a, inv_b = obstacles.inverse_axes if ops.nearest is not None else ops.inverse_axes
    if cfg.ego_turn_rate > 0:
        # A sample keeps the ego's turned box until it has travelled far enough to turn back (its heading falling by
        # ego_turn_rate per metre; the growth with it, linearly: the growth is concave in the heading, so this errs
        # by < 2 cm at 0.3 rad), and at least over the plan's first seconds as every plan does (ellipse_growth).
        travelled = jnp.maximum(ox - ox[:, :1], 0.0)  # (B, K), or (B, K_o) at the obstacle rows' nodes [m]
        per_metre = cfg.ego_turn_rate / jnp.maximum(jnp.abs(problem.ego_heading), 1e-6)
        turned = jnp.clip(1.0 - per_metre * travelled, 0.0, 1.0)
        grow_lat = jnp.maximum(problem.ellipse_growth[1, 0] * turned, problem.ellipse_growth[1])
        # 1 / (b_i + growth) without a division per obstacle: two Newton steps from 1 / (b_i + half the growth now),
        # relative error under 1e-3 (the growth is under a third of b_i) and always from below (ellipses never smaller).
        inv_b_mid = 1.0 / (obstacles.obstacle_b + 0.5 * problem.ellipse_growth[1, 0])  # (N,)
        # The longitudinal growth (< 0.3 m at 0.3 rad, on semi-axes of 7 m and more) is kept whole.
        inv_a_full = 1.0 / (obstacles.obstacle_a + problem.ellipse_growth[0, 0])

    def ellipse(i):
        """(x - x_o, y - y_o, 1 / ellipse ratio) of obstacle i, (B, K) each; i None: of every obstacle, (N, B, K)."""
        def pick(a):  # obstacle i's entry of an (N,) or (N, K) array; all of them shaped to broadcast against (N, B, K)
            return a[i] if i is not None else a.reshape(a.shape[0], 1, a.shape[1] if a.ndim == 2 else 1)
        dx, dy = ox - pick(obstacles.obstacle_x), oy - pick(obstacles.obstacle_y)
        if sparse is not None:  # semi-axes grown by the relative motion over the nodes left out (no barrier here: i set)
            long_axis = (obstacles.obstacle_a[i] + problem.ellipse_growth[0, 0] if cfg.ego_turn_rate > 0
                         else 1.0 / ops.inverse_axes[0, i])
            lat_axis = obstacles.obstacle_b[i] + grow_lat if cfg.ego_turn_rate > 0 else 1.0 / ops.inverse_axes[1, i]
            # 1 / axis as a fast reciprocal square root of its square: cheap operations only, which XLA fuses into
            # the obstacle's loop (a division would be computed in a loop of its own and materialised).
            long_axis = long_axis + _motion_growth(ego_steps[0], obstacle_steps[0], i, sparse.spread)
            lat_axis = lat_axis + _motion_growth(ego_steps[1], obstacle_steps[1], i, sparse.spread)
            dx_n, dy_n = dx * _fast_rsqrt(long_axis * long_axis), dy * _fast_rsqrt(lat_axis * lat_axis)
        elif cfg.ego_turn_rate > 0:
            b_i, mid = pick(obstacles.obstacle_b) + grow_lat, pick(inv_b_mid)
            inv_b_i = mid * (2.0 - b_i * mid)
            inv_b_i = inv_b_i * (2.0 - b_i * inv_b_i)
            dx_n, dy_n = dx * pick(inv_a_full), dy * inv_b_i
        else:
            dx_n, dy_n = dx * pick(inv_a), dy * pick(inv_b)
        return dx, dy, _fast_rsqrt(jnp.maximum(dx_n * dx_n + dy_n * dy_n, _EPS * _EPS))

    def scale_factor(i, inv_ratio):
        """h - x_o = (x - x_o) * d / ratio = (x - x_o) * scale with d = max(ratio, lower bound). The lower bound is
        lowered by the obstacle's recovery (1 - floor: 0 unless the ego starts inside the ellipse); with the barrier it
        follows the ratio at the previous node (the state holds the ratios shifted by one node)."""
        floors = ops.obstacle_floor if ops.nearest is None else ops.nearest.obstacle_floor
        floor = floors[i] if i is not None else floors[:, None, :]
        if not cfg.barrier:
            return jnp.maximum(1.0, floor * inv_ratio)
        prev = d_obs_prev[i] if i is not None else d_obs_prev
        return jnp.maximum(1.0, (1.0 + (1.0 - gamma_obs) * (prev - 1.0) - (1.0 - floor)) * inv_ratio)

    for i in range(obstacles.obstacle_x.shape[0]):
        dx, dy, inv_ratio = ellipse(i)
        scale = scale_factor(i, inv_ratio)
        m = obstacles.obstacle_mask[i]
        h_ox = h_ox + m * (obstacles.obstacle_x[i] + dx * scale)
        h_oy = h_oy + m * (obstacles.obstacle_y[i] + dy * scale)
        if with_residuals and not aggregate_obstacles:
            obstacle_sq = obstacle_sq + m * (dx * dx + dy * dy) * (1.0 - scale) ** 2
    one = jax.lax.complex(jnp.abs(ops.direction), 0.0 * ops.direction)  # 1 + 0i, known only at run time (_pair)
    h_ox, h_oy = _pair(h_ox, h_oy, one)
    d_obs_next = d_obs_prev
    if cfg.barrier:  # d = scale / inverse ratio of every obstacle
        inv_ratio = ellipse(None)[2]
        d_obs_next = _previous_node(scale_factor(None, inv_ratio) / inv_ratio)

    # Velocity and acceleration in polar form; curvature/centripetal bounds become bounds on lengths. Square roots and
    # divisions are fast reciprocal square roots (cheap operations), which XLA fuses into the loops of the two pairs
    # instead of giving each its own loop.
    speed, uvx, uvy = _normalise(vx, vy)
    acc, uax, uay = _normalise(ax, ay)
    if d_acc_prev is None:  # evaluating a given trajectory: its own acceleration sets the curvature bound
        d_acc_prev = acc
    sin_va = jnp.abs(uvx * uay - uvy * uax)
    v_lo = jnp.full_like(speed, cfg.v_min)
    # Curvature a_perp / v^2 is undefined for a stopped car: its bounds apply above CURVATURE_MIN_SPEED.
    turning = speed > CURVATURE_MIN_SPEED
    if cfg.kappa_max > 0:
        v_lo = jnp.where(turning, jnp.maximum(v_lo, _fast_sqrt(d_acc_prev * sin_va * (1.0 / cfg.kappa_max))), v_lo)
    # Centripetal bound on the car's own motion: beside the line the curvature k is of (at y0) the car moves at
    # (1 - k (y - y0)) x' on a path of curvature k / (1 - k (y - y0)): lateral acceleration x'^2 |k| (1 - k (y - y0)).
    x_rows, y_rows = (x, y) if P == K else (x[:, _row_nodes(P, K)], y[:, _row_nodes(P, K)])
    road_k = road_curvature_at(problem.road_curvature, x_rows)
    path_scale = jnp.maximum(1.0 - road_k * (y_rows - problem.road_origin), PATH_SCALE_MIN)
    v_curve = cfg.centripetal_max ** 0.5 * _fast_rsqrt(jnp.maximum(uvx * uvx * jnp.abs(road_k) * path_scale, _EPS))
    if cfg.recovery_time > 0:  # a car faster than a curve's speed comes down to it (recovery_from)
        v_curve = jnp.maximum(v_curve, ops.curve_recovery[0] * v_curve + ops.curve_recovery[1])
    v_hi = jnp.minimum(cfg.v_max, v_curve)
    # Course bound: a velocity turned further from the direction of travel (s = +-1 along x) than the bound goes to
    # the nearest point of the bound's ray, of length |v| cos(course - bound) (then the speed bounds apply); no
    # bound (P1): as it is. Above ``course_min_speed`` (by default CURVATURE_MIN_SPEED, as the curvature bound) the
    # bound is ``course_max``; below it a right angle: a velocity against the direction of travel goes to its
    # sideways part (0, vy), so a plan braked to rest does not roll back.
    along = speed
    dir_x, dir_y = uvx, uvy
    if cfg.course_max > 0:
        s = ops.direction
        fast = speed > cfg.course_min_speed
        cos_b, sin_b = jnp.where(fast, ops.course[0], 0.0), jnp.where(fast, ops.course[1], 1.0)
        turned = s * uvx < cos_b
        dir_x = jnp.where(turned, s * cos_b, uvx)
        dir_y = jnp.where(turned, jnp.where(uvy < 0, -sin_b, sin_b), uvy)
        along = jnp.where(turned, jnp.maximum(s * vx * cos_b + jnp.abs(vy) * sin_b, 0.0), speed)
    d_vel = jnp.minimum(jnp.maximum(along, v_lo), v_hi)
    vel_x, vel_y = _pair(d_vel * dir_x, d_vel * dir_y, one)
    a_hi = jnp.full_like(acc, cfg.a_max)
    if cfg.acceleration_recovery and cfg.recovery_time > 0:  # a car beyond the bound comes back within it in time
        a_hi = jnp.maximum(a_hi, ops.acceleration_recovery[0] * cfg.a_max + ops.acceleration_recovery[1])
    if cfg.kappa_max > 0:
        inv_sin = _fast_rsqrt(jnp.maximum(sin_va, _EPS))
        a_hi = jnp.where(turning, jnp.minimum(a_hi, cfg.kappa_max * (vel_x * vel_x + vel_y * vel_y) * inv_sin * inv_sin), a_hi)
    d_acc = jnp.clip(acc, 0.0, a_hi)
    acc_x, acc_y = _pair(d_acc * uax, d_acc * uay, one)

    # Lane rows with slack s = max(0, e - G c_y); the rows act on node values, so no extra matmul. Row k
    # (k = 1..K-1) is y[k] - (1 - g) y[k-1]; node 0 (fixed by A_eq) has none. Plain mode (g = 1 statically)
    # needs no shifted copies of y, which keeps this part in vectorised loops.
    g = ops.lane_gamma
    rows = y - (1.0 - g) * _shift_right(y) if cfg.barrier else y
    target_ub = jnp.minimum(rows, ops.lane_bounds[0])  # e - s of the upper rows
    target_lb = jnp.minimum(-rows, ops.lane_bounds[1])  # e - s of the lower rows
    t = ops.lane_rows * (target_ub - target_lb)
    lane_pull = t - (1.0 - g) * _shift_left(t) if cfg.barrier else t

    aggregate = with_residuals and aggregate_obstacles
    if aggregate:  # the products' operands materialised once, for them and for the residuals
        h_ox, h_oy, vel_x, vel_y, acc_x, acc_y, target_ub, target_lb, lane_pull = jax.lax.optimization_barrier(
            (h_ox, h_oy, vel_x, vel_y, acc_x, acc_y, target_ub, target_lb, lane_pull))
    # rho F'h per axis as three (B, K) x (K, n) products: no (B, 3K) concatenation is materialised.
    back_pos, back_vel, back_acc = ops.back[:K], ops.back[K:K + P], ops.back[K + P:]
    if sparse is None:
        pull = jnp.stack([
            (cfg.rho_obstacle * h_ox) @ back_pos + (cfg.rho_velocity * vel_x) @ back_vel
            + (cfg.rho_acceleration * acc_x) @ back_acc,
            (cfg.rho_obstacle * h_oy + cfg.rho_lane * lane_pull) @ back_pos + (cfg.rho_velocity * vel_y) @ back_vel
            + (cfg.rho_acceleration * acc_y) @ back_acc,
        ])  # (2, B, n)
    else:
        pull = jnp.stack([
            (cfg.rho_obstacle * h_ox) @ sparse.back + (cfg.rho_velocity * vel_x) @ back_vel
            + (cfg.rho_acceleration * acc_x) @ back_acc,
            (cfg.rho_obstacle * h_oy) @ sparse.back + (cfg.rho_lane * lane_pull) @ back_pos
            + (cfg.rho_velocity * vel_y) @ back_vel + (cfg.rho_acceleration * acc_y) @ back_acc,
        ])
    if not with_residuals:
        return pull, d_obs_next, d_acc, None
    free = ops.free_nodes
    free_obstacle = free[0] if sparse is None else sparse.free
    if aggregate:
        n_active = jnp.sum(obstacles.obstacle_mask, axis=0)  # per sample and node with the nearest obstacles
        return pull, d_obs_next, d_acc, Residuals(
            obstacle=_safe_sqrt(jnp.sum(free_obstacle * ((n_active * ox - h_ox) ** 2 + (n_active * oy - h_oy) ** 2), axis=1)),
            velocity=_safe_sqrt(jnp.sum(free[1] * ((vx - vel_x) ** 2 + (vy - vel_y) ** 2), axis=1)),
            acceleration=_safe_sqrt(jnp.sum(free[2] * ((ax - acc_x) ** 2 + (ay - acc_y) ** 2), axis=1)),
            lane=_safe_sqrt(jnp.sum(ops.lane_rows * ((rows - target_ub) ** 2 + (-rows - target_lb) ** 2), axis=1)),
        )
    if cfg.course_max > 0:
        velocity_sq = (vx - d_vel * dir_x) ** 2 + (vy - d_vel * dir_y) ** 2
    else:
        velocity_sq = (speed - d_vel) ** 2
    residuals = Residuals(
        obstacle=_safe_sqrt(jnp.sum(free_obstacle * obstacle_sq, axis=1)),
        velocity=_safe_sqrt(jnp.sum(free[1] * velocity_sq, axis=1)),
        acceleration=_safe_sqrt(jnp.sum(free[2] * (acc - d_acc) ** 2, axis=1)),
        lane=_safe_sqrt(jnp.sum(ops.lane_rows * ((rows - target_ub) ** 2 + (-rows - target_lb) ** 2), axis=1)),
    )
    return pull, d_obs_next, d_acc, residuals


def _steps(values: jnp.ndarray) -> jnp.ndarray:
    """(..., K_o) -> (2, ..., K_o): each node's change from the previous node and to the next (0 beyond the ends)."""
    change = values[..., 1:] - values[..., :-1]
    pad = [(0, 0)] * (values.ndim - 1)
    return jnp.stack([jnp.pad(change, pad + [(1, 0)]), jnp.pad(change, pad + [(0, 1)])])


def _motion_growth(ego_steps: jnp.ndarray, obstacle_steps: jnp.ndarray, i: int, spread: jnp.ndarray) -> jnp.ndarray:
    """[m] (B, K_o) growth of obstacle i's semi-axis along one axis at each obstacle-row node: the larger of the changes
    of the ego's coordinate relative to the obstacle's from the previous and to the next such node (``ego_steps`` (2, B,
    K_o) and ``obstacle_steps`` (2, N, K_o), :func:`_steps`), times their ``spread`` (:class:`_ObstacleNodes`), so that
    a node's ellipse covers the relative motion over the nodes left out around it (linear between the nodes with
    rows). Elementwise on arrays shared by the obstacles, so it fuses into each obstacle's loop."""
    before = jnp.abs(ego_steps[0] - obstacle_steps[0, i]) * spread[0]
    after = jnp.abs(ego_steps[1] - obstacle_steps[1, i]) * spread[1]
    return jnp.maximum(before, after)


def _stacked(coeffs: jnp.ndarray) -> jnp.ndarray:
    """(B, 2n) -> (2, B, n)."""
    return jnp.stack(split(coeffs))


def _flat(stacked: jnp.ndarray) -> jnp.ndarray:
    """(2, B, n) -> (B, 2n)."""
    return jnp.concatenate([stacked[0], stacked[1]], axis=1)


@float32_products
def project(
    model: TrajectoryModel,
    problem: PlanningProblem,
    target: jnp.ndarray,
    b_x: jnp.ndarray,
    b_y: jnp.ndarray,
    cfg: ProjectionConfig = ProjectionConfig(),
    *,
    gamma_obs=None,
    gamma_lane=None,
    init_coeffs: jnp.ndarray | None = None,
    init_multipliers: jnp.ndarray | None = None,
    unroll: bool = False,
    iterations: jax.Array | None = None,
) -> ProjectionResult:
    """Project the batch ``target`` (B, 2n) onto the constraint set.

    b_x (B, mx) or (mx,), b_y likewise: equality right-hand sides (see qp.boundary_values).
    gamma_obs, gamma_lane: barrier parameters in (0, 1], used when ``cfg.barrier``: a number, or (B,) /
    (B, 1) one per sample; None: ``cfg.gamma_obs`` / ``cfg.gamma_lane``.
    init_coeffs, init_multipliers: optional (B, 2n) warm start (P2 learns them); default target, 0.
    unroll: run exactly ``cfg.max_iterations`` steps with lax.scan (differentiable) instead of
    stopping early.
    iterations: the iterations to run, a traced count of at most ``cfg.max_iterations`` (one compiled loop runs
    different counts; unrolled, the steps past it leave the state as it is); None: ``cfg.max_iterations``.
    With ``cfg.max_iterations = 0`` the result is ``target`` itself (the initialisation is not used).
    """
    B = target.shape[0]
    N, K = problem.obstacle_x.shape
    gamma_obs = _per_sample(cfg.gamma_obs if gamma_obs is None else gamma_obs, B, "gamma_obs")
    gamma_lane = _per_sample(cfg.gamma_lane if gamma_lane is None else gamma_lane, B, "gamma_lane")
    ops = _operators(model, problem, cfg, gamma_lane)
    node_ops = _at_nodes(ops, model, problem, cfg)  # the residuals: every obstacle, the velocity and acceleration at the nodes
    rows_problem = problem  # the obstacles the rows act on
    if ops.obstacle_nodes is not None:  # their values at the nodes with rows
        nodes = obstacle_row_nodes(model.t, cfg)
        rows_problem = problem._replace(obstacle_x=problem.obstacle_x[:, nodes], obstacle_y=problem.obstacle_y[:, nodes],
                                        ellipse_growth=problem.ellipse_growth[:, nodes])
        ops = ops._replace(obstacle_floor=ops.obstacle_floor[:, nodes], inverse_axes=ops.inverse_axes[:, :, nodes],
                           obstacle_nodes=ops.obstacle_nodes._replace(
                               obstacle_steps=(_steps(rows_problem.obstacle_x), _steps(rows_problem.obstacle_y))))
    if 0 < cfg.nearest_obstacles < N:
        ratio = _target_ratios(model, problem, _stacked(target))
        if cfg.nearest_choice == "batch":
            rows_problem, ops = _nearest_for_batch(problem, ops, ratio, cfg.nearest_obstacles)
        else:
            ops = ops._replace(nearest=_nearest_obstacles(problem, ratio, cfg.nearest_obstacles, ops.obstacle_floor))
    # The boundary part of the linear solve never changes: compute it once.
    b_x, b_y = jnp.broadcast_to(b_x, (B, b_x.shape[-1])), jnp.broadcast_to(b_y, (B, b_y.shape[-1]))
    fixed = jnp.stack([b_x @ ops.boundary[0].T, b_y @ ops.boundary[1].T])
    target_s = _stacked(target)
    solve_t = jnp.swapaxes(ops.solve, 1, 2)
    sample_y = ops.per_sample
    if sample_y is not None:
        fixed = fixed.at[1].add(_batched_matvec(sample_y.boundary, b_y))

    def analyse(coeffs, d_obs, d_acc, with_residuals=False, aggregate_obstacles=False):
        return _analysis_step(coeffs, d_obs, d_acc, ops, rows_problem, cfg, gamma_obs, with_residuals, aggregate_obstacles)

    def measure(coeffs, d_obs):
        """The residuals of a result, at the nodes (the curvature bound from the trajectory's own acceleration)."""
        return _analysis_step(coeffs, d_obs, None, node_ops, problem, cfg, gamma_obs)[3]

    def solve(rhs):
        """(2, B, n) linear term -> the coefficients minimising the augmented Lagrangian with it."""
        coeffs = rhs @ solve_t + fixed
        return coeffs if sample_y is None else coeffs.at[1].add(_batched_matvec(sample_y.solve, rhs[1]))

    def penalise(coeffs):
        """rho F'F applied to (2, B, n)."""
        out = coeffs @ ops.penalty
        if sample_y is None:
            return out
        return out.at[1].add(jnp.sum(sample_y.penalty_weights * (coeffs[1] @ sample_y.penalty_terms), axis=0))

    def step(state: _State) -> _State:
        coeffs = solve(target_s + state.lam + state.pull)
        pull, d_obs, d_acc, _ = analyse(coeffs, state.d_obs, state.d_acc)
        # lambda <- lambda - rho F'(F xi - h) = lambda - rho F'F xi + rho F'h
        lam = state.lam - penalise(coeffs) + pull
        error = jnp.sqrt(jnp.max(jnp.sum((coeffs - state.coeffs) ** 2, axis=(0, 2))))
        return _State(coeffs, lam, pull, d_obs, d_acc, state.iteration + 1, error)

    if cfg.max_iterations == 0:  # nothing projected: the targets are the result
        init_coeffs = init_multipliers = None
    coeffs0 = target_s if init_coeffs is None else _stacked(init_coeffs)
    lam0 = jnp.zeros_like(target_s) if init_multipliers is None else _stacked(init_multipliers)
    d_obs0 = jnp.ones((N, B, K) if cfg.barrier else (0, B, K), target.dtype)
    pull0, d_obs0, d_acc0, _ = analyse(coeffs0, d_obs0, jnp.zeros((B, ops.derivative_rows), target.dtype))
    state = _State(coeffs0, lam0, pull0, d_obs0, d_acc0, jnp.asarray(0), jnp.asarray(jnp.inf, target.dtype))

    if cfg.anderson_window > 0 or cfg.relaxation != 1.0:
        return _accelerated(state, solve, analyse, measure, penalise, target_s, cfg, unroll, iterations)
    state = _loop(step, state, cfg, unroll, iterations)
    residuals = measure(state.coeffs, state.d_obs)
    status = jnp.where(state.error <= cfg.tolerance, ProjectionStatus.CONVERGED, ProjectionStatus.MAX_ITERATIONS)
    return ProjectionResult(_flat(state.coeffs), _flat(state.lam), residuals, state.iteration, status, state.error)


ANDERSON_SAFEGUARD = 1.0  # [-] an extrapolated point is kept where its constraint residual (``Residuals.total``) is at
# most this times that of the iterate it was extrapolated from
ANDERSON_MULTIPLIER_WEIGHT = 10.0  # [-] weight of the multipliers' part of the fixed-point residual (the primal violation
# rho F'(h - F xi)) against the pulls' part in Anderson's least-squares fit. Chosen on the built-in problems at 250 samples
# and 20 iterations: weights 1, 10, 30, 100 gave dense-snapshot medians 6.3, 5.1, 4.8, 5.3 and static-blockage 2.2, 1.4,
# 1.6, 1.4 (plain 6.3, 2.8); 10 had the lowest p90 on dense-snapshot and slow-leader-four-lane (11.5, 2.4; plain 12.3, 4.4)


class _AcceleratedState(NamedTuple):
    """The loop of :func:`_accelerated`. The fixed-point map acts on the multipliers and pulls (lam, pull), 4n numbers
    per sample (its rows, :func:`_rows`); the barrier's ratios and the acceleration lengths of the curvature bound
    follow the last accepted iterate's evaluation, as they follow the last iterate in the plain loop."""

    lam: jnp.ndarray  # (2, B, n) the point to evaluate next
    pull: jnp.ndarray  # (2, B, n)
    d_obs: jnp.ndarray  # (N, B, K) of the last accepted evaluation (the plain loop's d_obs after it)
    d_acc: jnp.ndarray  # (B, K) likewise
    candidate: jnp.ndarray  # (B,) the point to evaluate is an Anderson extrapolation (else a plain step)
    image: jnp.ndarray  # (B, 4n) the (relaxed) image of the last accepted point
    residual: jnp.ndarray  # (B, 4n) that image minus that point, weighted for the fit (ANDERSON_MULTIPLIER_WEIGHT)
    score: jnp.ndarray  # (B,) the constraint residual (Residuals.total) of the last accepted point's trajectory
    memory: anderson.Memory
    coeffs: jnp.ndarray  # (2, B, n) the last accepted point's coefficients: the result
    multipliers: jnp.ndarray  # (2, B, n) the multipliers of its image: the result's warm start
    iteration: jnp.ndarray  # () evaluations of the map (each costs one plain iteration)
    error: jnp.ndarray  # () max over samples of the accepted coefficient change (inf for a rejected extrapolation)


def _rows(lam: jnp.ndarray, pull: jnp.ndarray) -> jnp.ndarray:
    """(2, B, n) twice -> (B, 4n): one sample's state per row."""
    return jnp.concatenate([lam[0], lam[1], pull[0], pull[1]], axis=1)


def _unrows(rows: jnp.ndarray, n: int) -> tuple[jnp.ndarray, jnp.ndarray]:
    parts = [rows[:, i * n:(i + 1) * n] for i in range(4)]
    return jnp.stack(parts[:2]), jnp.stack(parts[2:])


def _loop(step, state, cfg: ProjectionConfig, unroll: bool, iterations):
    """``state`` after ``iterations`` (None: ``cfg.max_iterations``) applications of ``step``, fewer where no coefficient
    moves more than ``cfg.tolerance`` unless unrolled."""
    limit = cfg.max_iterations if iterations is None else iterations
    if not unroll:
        return jax.lax.while_loop(lambda s: (s.iteration < limit) & (s.error > cfg.tolerance), step, state)
    if iterations is None:
        return jax.lax.scan(lambda s, _: (step(s), None), state, None, length=cfg.max_iterations)[0]

    def masked(s, _):
        return jax.tree_util.tree_map(lambda new, old: jnp.where(s.iteration < limit, new, old), step(s), s), None
    return jax.lax.scan(masked, state, None, length=cfg.max_iterations)[0]


def _accelerated(state: _State, solve, analyse, measure, penalise, target_s, cfg: ProjectionConfig,
                 unroll: bool, iterations) -> ProjectionResult:
    """The alternating minimisation x <- G(x) on x = (lam, pull), over-relaxed (x <- x + ``relaxation`` (G(x) - x)) and
    Anderson-accelerated (:mod:`driveopt.anderson`, window ``anderson_window``), per sample with a safeguard: an
    extrapolated point is evaluated, and kept only where the constraint residual of its trajectory (``Residuals.total``,
    the curvature bound from the previous acceleration as in the iteration, the obstacles' part aggregated: see
    :func:`_analysis_step`) is at most :data:`ANDERSON_SAFEGUARD` times that of the accepted iterate it came from;
    elsewhere the plain image of that iterate is evaluated next and the sample's memory restarts. The fixed-point
    residual G(x) - x is the safeguard's first choice in the literature; here it is not a measure of progress: it first
    grows for ten iterations while the multipliers build up, and accepting what lowers it left the constraint residuals
    higher than the plain loop's (dense-snapshot after 20 iterations, 250 samples: median 10.8 against 6.3 with an
    unweighted fit, p90 15.4 against 12.3 with the weighted one). Anderson's fit weighs the multipliers' part of the
    residual by :data:`ANDERSON_MULTIPLIER_WEIGHT`. Each loop iteration evaluates G once, as a plain iteration does
    (plus the residuals and the fit, with a window: 1.1-1.7x a plain iteration's time on the CPU,
    docs/results/speed.md); the result is the last accepted point's coefficients (a plain solve of the KKT system, so
    the equality rows hold as in the plain loop)."""
    window, alpha = cfg.anderson_window, cfg.relaxation
    n, B = target_s.shape[-1], target_s.shape[1]
    dtype = target_s.dtype

    def per_row(mask, array, batch_axis):
        return mask.reshape((1,) * batch_axis + (B,) + (1,) * (array.ndim - batch_axis - 1))

    fit_weights = jnp.concatenate([jnp.full((2 * n,), ANDERSON_MULTIPLIER_WEIGHT, dtype), jnp.ones((2 * n,), dtype)])

    def step(s: _AcceleratedState) -> _AcceleratedState:
        coeffs = solve(target_s + s.lam + s.pull)
        pull, d_obs, d_acc, residuals = analyse(coeffs, s.d_obs, s.d_acc, with_residuals=window > 0,
                                                aggregate_obstacles=True)
        lam = s.lam - penalise(coeffs) + pull
        point = _rows(s.lam, s.pull)
        step_taken = alpha * (_rows(lam, pull) - point)
        image = point + step_taken
        residual = fit_weights * step_taken
        score = residuals.total if window > 0 else s.score
        accept = ~s.candidate | (score <= ANDERSON_SAFEGUARD * s.score)  # NaN: not accepted

        def pick(new, old, batch_axis):
            return jnp.where(per_row(accept, new, batch_axis), new, old)

        memory = s.memory
        if window > 0:
            memory = anderson.remember(memory, s.iteration % window, accept & (s.iteration > 0), accept,
                                       residual - s.residual, image - s.image)
        image, residual = pick(image, s.image, 0), pick(residual, s.residual, 0)
        change = jnp.sqrt(jnp.sum((coeffs - s.coeffs) ** 2, axis=(0, 2)))
        error = jnp.max(jnp.where(accept, change, jnp.inf))
        following = image
        candidate = jnp.zeros_like(accept)
        if window > 0:
            extrapolated = anderson.extrapolate(memory, residual, image)
            candidate = jnp.any(memory.valid, axis=1) & jnp.all(jnp.isfinite(extrapolated), axis=1)
            following = jnp.where(candidate[:, None], extrapolated, image)
        next_lam, next_pull = _unrows(following, n)
        return _AcceleratedState(
            next_lam, next_pull, pick(d_obs, s.d_obs, 1), pick(d_acc, s.d_acc, 0), candidate, image, residual,
            pick(score, s.score, 0), memory, pick(coeffs, s.coeffs, 1), pick(lam, s.multipliers, 1),
            s.iteration + 1, error)

    dim = 4 * n
    start = _AcceleratedState(
        state.lam, state.pull, state.d_obs, state.d_acc, jnp.zeros((B,), bool), jnp.zeros((B, dim), dtype),
        jnp.zeros((B, dim), dtype), jnp.full((B,), jnp.inf, dtype), anderson.empty(window, B, dim, dtype), state.coeffs,
        state.lam, state.iteration, state.error)
    final = _loop(step, start, cfg, unroll, iterations)
    residuals = measure(final.coeffs, final.d_obs)
    status = jnp.where(final.error <= cfg.tolerance, ProjectionStatus.CONVERGED, ProjectionStatus.MAX_ITERATIONS)
    return ProjectionResult(_flat(final.coeffs), _flat(final.multipliers), residuals, final.iteration, status, final.error)


def _batched_matvec(matrices: jnp.ndarray, vectors: jnp.ndarray) -> jnp.ndarray:
    """(B, n, m) x (B, m) -> (B, n), as a fused elementwise product and sum: for the planner's 1000 small matrices
    about 2.5x faster on CPU than the batched dot that ``einsum`` emits."""
    return jnp.sum(matrices * vectors[:, None, :], axis=-1)


def _per_sample(gamma, B: int, name: str):
    """A barrier parameter as given (a number) or, given per sample ((B,) or (B, 1)), as (B, 1)."""
    if jnp.ndim(gamma) == 0:
        return gamma
    if jnp.shape(gamma) not in ((B,), (B, 1)):
        raise ValueError(f"{name} must be a number or one per sample ({B},) or ({B}, 1), got shape {jnp.shape(gamma)}")
    return jnp.reshape(gamma, (B, 1))


@float32_products
def constraint_residuals(
    model: TrajectoryModel, problem: PlanningProblem, coeffs: jnp.ndarray, cfg: ProjectionConfig = ProjectionConfig()
) -> Residuals:
    """Distances of trajectories (B, 2n) to the feasible set, per family, without projecting them: the plain
    constraints (gamma = 1 whatever ``cfg.gamma_obs`` / ``cfg.gamma_lane``), i.e. the safety bounds themselves."""
    ops = _at_nodes(_operators(model, problem, cfg, 1.0), model, problem, cfg)
    B, K = coeffs.shape[0], model.W.shape[0]
    d_obs = jnp.ones((problem.obstacle_x.shape[0] if cfg.barrier else 0, B, K), coeffs.dtype)
    return _analysis_step(_stacked(coeffs), d_obs, None, ops, problem, cfg, 1.0)[3]
