"""Set-point QP against an independent float64 reference, and its gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from driveopt.basis import make_basis
from driveopt.config import BasisConfig, QPConfig
from driveopt.qp import boundary_values, make_model, segment_matrix, shift_setpoints, solve_setpoint_qp, split


def reference_solution(qp: QPConfig, p: np.ndarray, init_x, init_y, goal=None) -> np.ndarray:
    """Null-space method on the least-squares form of the cost, float64 (no KKT inverse involved)."""
    b = make_basis(BasisConfig())
    R = segment_matrix(len(b.t))
    v_d, y_d = R @ p[:4], R @ p[4:]
    ws, wv, wy = np.sqrt(qp.w_smooth), np.sqrt(qp.w_speed), np.sqrt(qp.w_lateral)
    # x: rows of sqrt(w) * (linear map) c - target
    Ax = np.vstack([ws * b.Wdd, wv * (b.Wdd + qp.k_pv * b.Wd)])
    rx = np.concatenate([np.zeros(len(b.t)), wv * qp.k_pv * v_d])
    Ay = np.vstack([ws * b.Wdd, wy * (b.Wdd + qp.k_p * b.W + qp.k_d * b.Wd)])
    ry = np.concatenate([np.zeros(len(b.t)), wy * qp.k_p * y_d])
    hard = qp.initial_acceleration
    hard_y = hard and qp.initial_lateral_acceleration
    Ex = [b.W[0], b.Wd[0]] + ([b.Wdd[0]] if hard else [])
    ex = list(init_x[:3 if hard else 2])
    Ey = [b.W[0], b.Wd[0]] + ([b.Wdd[0]] if hard_y else []) + [b.Wd[-1]]
    ey = list(init_y[:3 if hard_y else 2]) + [0.0]
    if goal is not None:
        Ex.append(b.W[-1])
        ex.append(goal[0])
        Ey.append(b.W[-1])
        ey.append(goal[1])

    def solve(A, r, E, e):
        E, e = np.array(E), np.array(e)
        c0 = np.linalg.lstsq(E, e, rcond=None)[0]
        _, _, Vt = np.linalg.svd(E)
        Z = Vt[E.shape[0]:].T
        z = np.linalg.lstsq(A @ Z, r - A @ c0, rcond=None)[0]
        return c0 + Z @ z

    return np.concatenate([solve(Ax, rx, Ex, ex), solve(Ay, ry, Ey, ey)])


@pytest.mark.parametrize("terminal, lateral", [(False, False), (True, False), (False, True)])
def test_batch_qp_matches_float64_reference(terminal, lateral):
    qp = QPConfig(terminal_position=terminal, initial_lateral_acceleration=lateral)
    model = make_model(BasisConfig(), qp)
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(5, 30, (16, 4)), rng.uniform(-2, 14, (16, 4))])
    init_x, init_y = np.array([0.0, 14.0, 0.5]), np.array([4.0, 0.3, -0.2])
    goal = np.column_stack([rng.uniform(150, 300, 16), rng.uniform(0, 12, 16)]) if terminal else None
    b_x, b_y = boundary_values(jnp.asarray(init_x), jnp.asarray(init_y), qp, None if goal is None else jnp.asarray(goal))
    coeffs = np.asarray(solve_setpoint_qp(model, jnp.asarray(p, jnp.float32), b_x, b_y))
    W = np.asarray(model.W, np.float64)
    for j in range(len(p)):
        ref = reference_solution(qp, p[j], init_x, init_y, None if goal is None else goal[j])
        cx, cy = coeffs[j, :11], coeffs[j, 11:]
        # Compare trajectories (what matters), in metres, against the float64 reference.
        np.testing.assert_allclose(W @ cx, W @ ref[:11], atol=2e-3 * max(1.0, np.abs(W @ ref[:11]).max()))
        np.testing.assert_allclose(W @ cy, W @ ref[11:], atol=2e-3)


def test_boundary_conditions_hold():
    qp = QPConfig()
    model = make_model(BasisConfig(), qp)
    b_x, b_y = boundary_values(jnp.array([0.0, 12.0, 1.0]), jnp.array([8.0, -0.5, 0.2]), qp)
    p = jnp.array([[25.0] * 4 + [0.0] * 4])
    cx, cy = split(solve_setpoint_qp(model, p, b_x, b_y)[0])
    np.testing.assert_allclose([model.W[0] @ cx, model.Wd[0] @ cx, model.Wdd[0] @ cx], [0.0, 12.0, 1.0], atol=1e-4)
    # by default the lateral acceleration starts free (the steering can jump); P1 imposes it too
    np.testing.assert_allclose([model.W[0] @ cy, model.Wd[0] @ cy, model.Wd[-1] @ cy], [8.0, -0.5, 0.0], atol=1e-4)
    assert abs(float(model.Wdd[0] @ cy) - 0.2) > 0.1
    p1 = QPConfig(initial_lateral_acceleration=True)
    model = make_model(BasisConfig(), p1)
    b_x, b_y = boundary_values(jnp.array([0.0, 12.0, 1.0]), jnp.array([8.0, -0.5, 0.2]), p1)
    cx, cy = split(solve_setpoint_qp(model, p, b_x, b_y)[0])
    np.testing.assert_allclose([model.W[0] @ cy, model.Wd[0] @ cy, model.Wdd[0] @ cy, model.Wd[-1] @ cy], [8.0, -0.5, 0.2, 0.0], atol=1e-4)


def test_gradients_match_finite_differences():
    qp = QPConfig()
    model = make_model(BasisConfig(), qp)

    def end_state(p, init):
        b_x, b_y = boundary_values(init[:3], init[3:], qp)
        c = solve_setpoint_qp(model, p[None], b_x, b_y)[0]
        cx, cy = split(c)
        return jnp.stack([model.W[-1] @ cx, model.Wd[50] @ cx, model.W[60] @ cy, model.Wdd[10] @ cy])

    p0 = jnp.array([18.0, 20.0, 22.0, 21.0, 4.0, 6.0, 8.0, 8.0])
    s0 = jnp.array([0.0, 15.0, 0.3, 4.0, 0.1, 0.0])
    jac_p, jac_s = jax.jacfwd(end_state, argnums=(0, 1))(p0, s0)
    h = 0.5  # the map is affine: central differences are exact up to rounding
    for arg, jac in ((0, jac_p), (1, jac_s)):
        base = (p0, s0)[arg]
        for i in range(base.shape[0]):
            e = jnp.zeros_like(base).at[i].set(h)
            args_hi, args_lo = [p0, s0], [p0, s0]
            args_hi[arg], args_lo[arg] = base + e, base - e
            fd = (end_state(*args_hi) - end_state(*args_lo)) / (2 * h)
            np.testing.assert_allclose(jac[:, i], fd, rtol=2e-2, atol=2e-3)
    assert float(jnp.abs(jac_p).max()) > 0.1  # set-points do move the trajectory


def test_goal_requires_terminal_position_flag():
    with pytest.raises(ValueError, match="goal"):
        boundary_values(jnp.zeros(3), jnp.zeros(3), QPConfig(), goal=jnp.zeros(2))


def test_free_initial_acceleration_matches_float64_reference():
    """Without the initial accelerations imposed the plan may start with any acceleration (a command that jumps)."""
    qp = QPConfig(initial_acceleration=False)
    model = make_model(BasisConfig(), qp)
    rng = np.random.default_rng(1)
    p = np.column_stack([rng.uniform(5, 30, (8, 4)), rng.uniform(-2, 14, (8, 4))])
    init_x, init_y = np.array([0.0, 14.0, -3.0]), np.array([4.0, 0.3, 1.5])
    b_x, b_y = boundary_values(jnp.asarray(init_x), jnp.asarray(init_y), qp)
    coeffs = np.asarray(solve_setpoint_qp(model, jnp.asarray(p, jnp.float32), b_x, b_y))
    Wdd0 = np.asarray(model.Wdd, np.float64)[0]
    start = []
    for j in range(len(p)):
        np.testing.assert_allclose(coeffs[j], reference_solution(qp, p[j], init_x, init_y), rtol=2e-3, atol=2e-2)
        c_x, c_y = split(coeffs[j])
        start.append(abs(Wdd0 @ c_x - init_x[2]) + abs(Wdd0 @ c_y - init_y[2]))
    assert float(np.median(start)) > 20.0  # [m/s^2] the PD tracking pulls hard at t = 0, far from the current acceleration


def test_shifted_set_points_are_the_step_functions_means_over_the_later_quarters():
    """Against the step functions sampled finely: each new quarter's value is the mean, over that quarter moved by the
    shift, of the old values (the last held beyond the horizon); no shift leaves them, a whole quarter moves them one on."""
    setpoints = np.array([[10.0, 9.0, 7.0, 8.0, 0.0, 0.0, 4.0, 4.0], [1.0, 2.0, 3.0, 4.0, -1.0, 2.0, -3.0, 5.0]], np.float32)
    np.testing.assert_array_equal(shift_setpoints(setpoints, 0.0), setpoints)
    np.testing.assert_array_equal(shift_setpoints(setpoints, 1.0)[0], [9.0, 7.0, 8.0, 8.0, 0.0, 4.0, 4.0, 4.0])
    for quarters in (0.053, 0.5, 1.7, 6.0):
        fine = (np.arange(400) + 0.5) / 100.0  # 100 samples per quarter, at their middles
        old_quarter = np.minimum(np.floor(fine + quarters), 3).astype(int)  # of each sample, the last held beyond
        for row, shifted in zip(setpoints, shift_setpoints(setpoints, quarters)):
            for axis in (slice(0, 4), slice(4, 8)):
                means = row[axis][old_quarter].reshape(4, 100).mean(axis=1)
                np.testing.assert_allclose(shifted[axis], means, atol=0.02 * np.ptp(row[axis]) + 1e-6)
    with pytest.raises(ValueError, match="quarters"):
        shift_setpoints(setpoints, -0.1)
