import numpy as np
import pytest

from driveopt.basis import basis_at, bernstein, derivative_control_points, make_basis
from driveopt.checks import ConfigError
from driveopt.config import BasisConfig


def test_partition_of_unity_and_derivative_sums():
    b = make_basis()
    np.testing.assert_allclose(b.W.sum(1), 1.0, atol=1e-12)
    np.testing.assert_allclose(b.Wd.sum(1), 0.0, atol=1e-12)
    np.testing.assert_allclose(b.Wdd.sum(1), 0.0, atol=1e-12)


def test_derivatives_exact_for_a_polynomial():
    """Fit a degree-7 polynomial exactly and compare its basis derivatives to the analytic ones."""
    T = 15.0
    t = np.linspace(0, T, 100)
    poly = np.polynomial.Polynomial([1.0, -0.5, 0.3, 0.02, -0.004, 1e-4, -2e-6, 3e-8])
    b = basis_at(10, T, t)
    coeffs, *_ = np.linalg.lstsq(b.W, poly(t), rcond=None)
    np.testing.assert_allclose(b.W @ coeffs, poly(t), atol=1e-8)
    np.testing.assert_allclose(b.Wd @ coeffs, poly.deriv(1)(t), atol=1e-7)
    np.testing.assert_allclose(b.Wdd @ coeffs, poly.deriv(2)(t), atol=1e-6)


@pytest.mark.parametrize("pieces", [1, 3, 4])
def test_derivative_control_points_give_the_derivatives_and_bound_them(pieces):
    """On each piece, the velocity and (degree-raised) acceleration control points are Bernstein polynomials of
    order - 1 equal to the basis's derivatives, and their largest magnitude bounds the derivative's magnitude at every
    time (convex hull)."""
    T, order = 15.0, 10
    t = np.linspace(0, T, 1001)
    b = basis_at(order, T, t)
    velocity, acceleration = derivative_control_points(order, T, pieces)
    assert velocity.shape == acceleration.shape == (pieces * (order - 1) + 1, order + 1)
    coeffs = np.random.default_rng(0).normal(0.0, 30.0, (50, 2, order + 1))
    for points, derivative in ((velocity, b.Wd), (acceleration, b.Wdd)):
        for k in range(pieces):  # piece k: times [k T / pieces, (k + 1) T / pieces], points k (order - 1) .. (k + 1) (order - 1)
            inside = (t >= k * T / pieces) & (t <= (k + 1) * T / pieces)
            piece = points[k * (order - 1):(k + 1) * (order - 1) + 1]
            np.testing.assert_allclose(bernstein(order - 1, t[inside] * pieces / T - k) @ piece @ coeffs[0, 0],
                                       derivative[inside] @ coeffs[0, 0], rtol=1e-9, atol=1e-9)
        bound = np.hypot(*(coeffs @ points.T).transpose(1, 0, 2)).max(axis=1)  # (50,) largest control-point magnitude
        assert np.all(np.hypot(*(coeffs @ derivative.T).transpose(1, 0, 2)).max(axis=1) <= bound + 1e-9)


def test_configurable_horizon_and_nodes():
    b = make_basis(BasisConfig(order=8, horizon=6.0, num_nodes=40))
    assert b.W.shape == (40, 9) and b.t[-1] == pytest.approx(6.0)


@pytest.mark.parametrize("kwargs", [dict(order=1), dict(horizon=-1.0), dict(num_nodes=30), dict(horizon=float("nan"))])
def test_bad_basis_config_is_rejected(kwargs):
    with pytest.raises(ConfigError):
        BasisConfig(**kwargs)
