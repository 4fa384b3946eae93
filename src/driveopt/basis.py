"""Bernstein polynomial basis on [0, T] with exact time derivatives (DESIGN §2.1).

A trajectory axis is ``x(t) = W(t) @ c`` with ``c`` the ``order + 1`` Bernstein
coefficients; ``Wd`` and ``Wdd`` are the exact first and second time derivatives
(the ``1/T`` chain-rule factors included). Matrices are built in float64 with
numpy; callers cast them to the working precision.
"""

from __future__ import annotations

from math import comb
from typing import NamedTuple

import numpy as np

from driveopt.config import BasisConfig


class Basis(NamedTuple):
    """Basis matrices evaluated at the time nodes. Shapes: t (K,), W/Wd/Wdd (K, n+1)."""

    t: np.ndarray  # [s]
    W: np.ndarray  # [-]
    Wd: np.ndarray  # [1/s]
    Wdd: np.ndarray  # [1/s^2]


def bernstein(order: int, tau: np.ndarray) -> np.ndarray:
    """Bernstein polynomials B_{i,order}(tau), i = 0..order, for tau in [0, 1]. Shape (len(tau), order+1)."""
    tau = np.asarray(tau, dtype=np.float64)[:, None]
    i = np.arange(order + 1)[None, :]
    binom = np.array([comb(order, k) for k in range(order + 1)], dtype=np.float64)[None, :]
    return binom * tau**i * (1.0 - tau) ** (order - i)


def _derivative_matrix(order: int) -> np.ndarray:
    """D with d/dtau [B_{.,order}] = B_{.,order-1} @ D, shape (order, order+1)."""
    D = np.zeros((order, order + 1))
    for i in range(order):
        D[i, i] = -order
        D[i, i + 1] = order
    return D


def _elevation_matrix(order: int) -> np.ndarray:
    """E with the control points of a Bernstein polynomial of ``order`` raised to ``order + 1`` being E @ p, shape
    (order+2, order+1): q_i = i/(order+1) p_{i-1} + (1 - i/(order+1)) p_i."""
    E = np.zeros((order + 2, order + 1))
    for i in range(order + 2):
        w = i / (order + 1)
        if i > 0:
            E[i, i - 1] = w
        if i <= order:
            E[i, i] = 1.0 - w
    return E


def _restriction_matrix(order: int, start: float, end: float) -> np.ndarray:
    """R with the control points of a Bernstein polynomial of ``order`` on [0, 1] restricted to [start, end] (as a
    polynomial of its own on that piece, rescaled to [0, 1]) being R @ p, shape (order+1, order+1)."""
    tau = np.linspace(0.0, 1.0, order + 1)
    return np.linalg.solve(bernstein(order, tau), bernstein(order, start + (end - start) * tau))


def derivative_control_points(order: int, horizon: float, pieces: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(V, A), each (P, order+1): the control points of the velocity [m/s] (a Bernstein polynomial of ``order - 1``) are
    V @ c and those of the acceleration [m/s^2] (``order - 2``, raised to ``order - 1`` so that both have their points
    at the same abscissae) are A @ c. With ``pieces`` > 1 the horizon is split into that many equal pieces and the
    points are those of each piece, the points that two pieces share (the value at their boundary) taken once:
    P = pieces (order - 1) + 1, the abscissa of point i being i / (P - 1) of the horizon.

    A polynomial stays in the convex hull of its control points, so a convex bound (a speed or acceleration magnitude)
    met at every point of a piece holds at every time of it. The points of a whole horizon can lie far outside the
    curve (a plan moving 3 m aside and 7 m back within 6 s of its 15 s, order 10: velocity points up to 348 m/s for a
    speed of at most 22 m/s); more pieces bring them closer to the curve (there: 35, 23 and 22 m/s with 2, 4 and 8).
    Raising the degree keeps the hull property (the new points are convex combinations of the old)."""
    D1 = _derivative_matrix(order)
    D2 = _elevation_matrix(order - 2) @ _derivative_matrix(order - 1) @ D1
    m = order - 1  # the derivatives' order
    keep = [np.arange(m + 1) if k == 0 else np.arange(1, m + 1) for k in range(pieces)]
    R = np.concatenate([_restriction_matrix(m, k / pieces, (k + 1) / pieces)[rows] for k, rows in enumerate(keep)]) \
        if pieces > 1 else np.eye(m + 1)
    return R @ D1 / horizon, R @ D2 / horizon**2


def basis_at(order: int, horizon: float, t: np.ndarray) -> Basis:
    """Evaluate W, W', W'' at arbitrary times t in [0, horizon] [s]."""
    t = np.asarray(t, dtype=np.float64)
    tau = t / horizon
    D1 = _derivative_matrix(order)  # (n, n+1)
    D2 = _derivative_matrix(order - 1) @ D1  # (n-1, n+1)
    W = bernstein(order, tau)
    Wd = bernstein(order - 1, tau) @ D1 / horizon
    Wdd = bernstein(order - 2, tau) @ D2 / horizon**2
    return Basis(t, W, Wd, Wdd)


def make_basis(config: BasisConfig = BasisConfig()) -> Basis:
    """Basis at ``config.num_nodes`` equally spaced nodes on [0, horizon]."""
    t = np.linspace(0.0, config.horizon, config.num_nodes)
    return basis_at(config.order, config.horizon, t)
