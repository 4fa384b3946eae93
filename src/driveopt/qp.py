"""Set-point QP (DESIGN §2.2): behavioural set-points -> Bernstein coefficients, for a whole batch.

Per axis the cost is quadratic with a Hessian and equality rows that do not depend
on the set-points, so the KKT matrix is inverted once (float64, numpy) when the
model is built and the batch solve is the affine map

    c_x = speed_map @ v_set + init_map_x @ b_x
    c_y = lateral_map @ y_set + init_map_y @ b_y

which is exactly differentiable in the set-points and in the boundary values.
Coefficients are stacked ``xi = (c_x, c_y)`` with ``2 * (order + 1)`` entries.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from driveopt.basis import Basis, make_basis
from driveopt.config import BasisConfig, QPConfig
from driveopt.xla import float32_products

NUM_SEGMENTS = 4  # set-points per axis; each holds over a quarter of the horizon
SETPOINT_DIM = 2 * NUM_SEGMENTS  # p = (v_1..v_4 [m/s], y_1..y_4 [m])


def shift_setpoints(setpoints: np.ndarray, quarters: float) -> np.ndarray:
    """(..., 8) set-points seen ``quarters`` [-] of the horizon's quarters later: each axis's step function (a value held
    over each quarter, the last one beyond the horizon) moved that much earlier, each quarter's new value its mean over
    the quarter. A plan handed on to the next call keeps its timing this way (a lane change it makes in 4 s is made
    in 3.8 s by the call 0.2 s later, not again in 4 s)."""
    if quarters < 0:
        raise ValueError(f"quarters must be at least 0, got {quarters:g}")
    starts = np.arange(NUM_SEGMENTS, dtype=np.float64)
    ends = np.append(starts[1:], np.inf)  # the last value holds beyond the horizon
    window_from, window_to = starts + quarters, starts + 1.0 + quarters  # the new quarters on the old time axis
    overlap = np.maximum(np.minimum(window_to[:, None], ends) - np.maximum(window_from[:, None], starts), 0.0)  # (new, old)
    setpoints = np.asarray(setpoints)
    values = setpoints.astype(np.float64).reshape(*setpoints.shape[:-1], 2, NUM_SEGMENTS)  # (..., axis, old)
    return (values @ overlap.T).reshape(setpoints.shape).astype(setpoints.dtype)


class TrajectoryModel(NamedTuple):
    """Constant arrays shared by the QP, the projection and the costs (float32 numpy).

    n = order + 1 coefficients per axis, K nodes, mx / my equality rows per axis.
    """

    t: jnp.ndarray  # (K,) [s]
    W: jnp.ndarray  # (K, n)
    Wd: jnp.ndarray  # (K, n) [1/s]
    Wdd: jnp.ndarray  # (K, n) [1/s^2]
    A_x: jnp.ndarray  # (mx, n) equality rows of the x axis
    A_y: jnp.ndarray  # (my, n) equality rows of the y axis
    speed_map: jnp.ndarray  # (n, 4) d c_x / d v_set
    lateral_map: jnp.ndarray  # (n, 4) d c_y / d y_set
    init_map_x: jnp.ndarray  # (n, mx) d c_x / d b_x
    init_map_y: jnp.ndarray  # (n, my) d c_y / d b_y
    free_nodes: jnp.ndarray  # (3, K) 1 where (position, velocity, acceleration) at a node is not fixed by A_eq
    fit_x: jnp.ndarray  # (n, K) least-squares fit of x positions at the nodes, under A_x c = b_x ...
    fit_bx: jnp.ndarray  # (n, mx) ... plus this times b_x
    fit_y: jnp.ndarray  # (n, K) same for y
    fit_by: jnp.ndarray  # (n, my)


def segment_matrix(num_nodes: int) -> np.ndarray:
    """(K, 4) matrix repeating each of the 4 set-points over its quarter of the nodes."""
    R = np.zeros((num_nodes, NUM_SEGMENTS))
    per = num_nodes // NUM_SEGMENTS
    for m in range(NUM_SEGMENTS):
        R[m * per:(m + 1) * per, m] = 1.0
    return R


def equality_rows(basis: Basis, qp: QPConfig) -> tuple[np.ndarray, np.ndarray]:
    """Equality rows (A_x, A_y): initial x, x', x'' (and x(T)); initial y, y', y'', y'(T) (and y(T)).

    x(T) and y(T) are rows when ``qp.terminal_position``; x(T) not when ``qp.terminal_longitudinal`` is False.

    The initial accelerations are left out when ``qp.initial_acceleration`` is False, the lateral one
    also when ``qp.initial_lateral_acceleration`` is False (:func:`imposed_accelerations`).
    """
    impose_x, impose_y = imposed_accelerations(qp)
    rows_x = [basis.W[0], basis.Wd[0]] + ([basis.Wdd[0]] if impose_x else [])
    rows_y = [basis.W[0], basis.Wd[0]] + ([basis.Wdd[0]] if impose_y else []) + [basis.Wd[-1]]
    if qp.terminal_position:
        if qp.terminal_longitudinal:
            rows_x.append(basis.W[-1])
        rows_y.append(basis.W[-1])
    return np.stack(rows_x), np.stack(rows_y)


def imposed_accelerations(qp: QPConfig) -> tuple[bool, bool]:
    """Whether the plan must start from the current (x'', y'') (equality rows) on each axis."""
    return qp.initial_acceleration, qp.initial_acceleration and qp.initial_lateral_acceleration


def quadratic_costs(basis: Basis, qp: QPConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Hessians and set-point gradient maps of the two axes, for cost 0.5 c'Hc + (G s)'c.

    x: w_s |W''c|^2 + w_v |W''c + k_pv (W'c - v_d)|^2
    y: w_s |W''c|^2 + w_y |W''c + k_p (W c - y_d) + k_d W'c|^2
    """
    R = segment_matrix(len(basis.t))
    M = basis.Wdd + qp.k_pv * basis.Wd
    N = basis.Wdd + qp.k_p * basis.W + qp.k_d * basis.Wd
    smooth = basis.Wdd.T @ basis.Wdd
    H_x = 2.0 * (qp.w_smooth * smooth + qp.w_speed * M.T @ M)
    H_y = 2.0 * (qp.w_smooth * smooth + qp.w_lateral * N.T @ N)
    G_x = -2.0 * qp.w_speed * qp.k_pv * M.T @ R
    G_y = -2.0 * qp.w_lateral * qp.k_p * N.T @ R
    return H_x, G_x, H_y, G_y


def _affine_solution(H: np.ndarray, G: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(set-point map, boundary map) of argmin 0.5 c'Hc + (G s)'c s.t. A c = b, via one KKT inverse."""
    n, m = H.shape[0], A.shape[0]
    kkt = np.block([[H, A.T], [A, np.zeros((m, m))]])
    inv = np.linalg.inv(kkt)
    return -inv[:n, :n] @ G, inv[:n, n:]


@functools.lru_cache(maxsize=32)
def make_model(basis_config: BasisConfig = BasisConfig(), qp: QPConfig = QPConfig()) -> TrajectoryModel:
    """Build (once per configuration) every constant array of the planner."""
    basis = make_basis(basis_config)
    A_x, A_y = equality_rows(basis, qp)
    H_x, G_x, H_y, G_y = quadratic_costs(basis, qp)
    speed_map, init_map_x = _affine_solution(H_x, G_x, A_x)
    lateral_map, init_map_y = _affine_solution(H_y, G_y, A_y)
    free_nodes = np.ones((3, basis_config.num_nodes))
    free_nodes[:3 if all(imposed_accelerations(qp)) else 2, 0] = 0.0  # acceleration at t = 0: fixed only when both axes are

    # numpy (not jnp) constants: the cache must never hold values created under a jit trace.
    f32 = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
    return TrajectoryModel(
        f32(basis.t), f32(basis.W), f32(basis.Wd), f32(basis.Wdd), f32(A_x), f32(A_y),
        f32(speed_map), f32(lateral_map), f32(init_map_x), f32(init_map_y), f32(free_nodes),
        *(f32(a) for a in (*_fit_maps(basis, A_x), *_fit_maps(basis, A_y))),
    )


FIT_SMOOTHING = 1e-2  # [s^4] weight of |c''|^2 against the squared position error [m^2] in fits


def _fit_maps(basis: Basis, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Maps (target map, boundary map) of argmin |W c - target|^2 + s |W'' c|^2 s.t. A c = b."""
    H = 2.0 * (basis.W.T @ basis.W + FIT_SMOOTHING * basis.Wdd.T @ basis.Wdd)
    target_map, boundary_map = _affine_solution(H, -2.0 * basis.W.T, A)
    return target_map, boundary_map


def fit_positions(model: TrajectoryModel, x: jnp.ndarray, y: jnp.ndarray, b_x: jnp.ndarray, b_y: jnp.ndarray) -> jnp.ndarray:
    """Coefficients (..., 2n) closest to node positions x, y (..., K) [m] that meet the equality rows."""
    c_x = x @ model.fit_x.T + b_x @ model.fit_bx.T
    c_y = y @ model.fit_y.T + b_y @ model.fit_by.T
    return jnp.concatenate([c_x, c_y], axis=-1)



def boundary_values(
    init_x: jnp.ndarray, init_y: jnp.ndarray, qp: QPConfig, goal: jnp.ndarray | None = None
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Right-hand sides (b_x, b_y) matching :func:`equality_rows`.

    init_x, init_y: (..., 3) position, velocity, acceleration at t = 0 (acceleration unused when
    ``qp.initial_acceleration`` is False).

    goal: (..., 2) terminal (x_f, y_f) [m], required iff ``qp.terminal_position`` (x_f unused when
    ``qp.terminal_longitudinal`` is False).
    """
    if qp.terminal_position != (goal is not None):
        raise ValueError("goal must be given exactly when qp.terminal_position is set")
    init_x = jnp.asarray(init_x)
    init_y = jnp.asarray(init_y)
    if goal is not None:
        shape = jnp.broadcast_shapes(init_x.shape[:-1], goal.shape[:-1])
        init_x = jnp.broadcast_to(init_x, shape + (3,))
        init_y = jnp.broadcast_to(init_y, shape + (3,))
    zero = jnp.zeros(init_y.shape[:-1] + (1,), init_y.dtype)
    used_x, used_y = (3 if imposed else 2 for imposed in imposed_accelerations(qp))
    parts_x, parts_y = [init_x[..., :used_x]], [init_y[..., :used_y], zero]
    if goal is not None:
        if qp.terminal_longitudinal:
            parts_x.append(goal[..., :1])
        parts_y.append(goal[..., 1:2])
    return jnp.concatenate(parts_x, -1), jnp.concatenate(parts_y, -1)


@float32_products
def solve_setpoint_qp(model: TrajectoryModel, setpoints: jnp.ndarray, b_x: jnp.ndarray, b_y: jnp.ndarray) -> jnp.ndarray:
    """Batch set-point QP. setpoints (B, 8) = (v_1..v_4 [m/s], y_1..y_4 [m]) -> coefficients (B, 2n)."""
    c_x = setpoints[..., :NUM_SEGMENTS] @ model.speed_map.T + b_x @ model.init_map_x.T
    c_y = setpoints[..., NUM_SEGMENTS:] @ model.lateral_map.T + b_y @ model.init_map_y.T
    return jnp.concatenate([c_x, c_y], axis=-1)


def split(coeffs: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(c_x, c_y) halves of stacked coefficients."""
    n = coeffs.shape[-1] // 2
    return coeffs[..., :n], coeffs[..., n:]


@float32_products
def qp_layer(model: TrajectoryModel, qp: QPConfig, setpoints, init_x, init_y) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Set-points (B, 8) -> (coefficients (B, 2n), node positions (B, K, 2) [m]): the set-point QP as a
    differentiable layer (the learned priors' decoders end in it)."""
    b_x, b_y = boundary_values(init_x, init_y, qp)
    coeffs = solve_setpoint_qp(model, setpoints, b_x, b_y)
    c_x, c_y = split(coeffs)
    return coeffs, jnp.stack([c_x @ model.W.T, c_y @ model.W.T], axis=-1)

