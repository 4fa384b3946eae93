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
