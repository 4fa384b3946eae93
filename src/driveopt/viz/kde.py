"""One-dimensional Gaussian kernel density estimate (numpy), for the set-point densities of P2 Fig. 1.

    density = gaussian_kde(samples, grid)            # Scott's bandwidth
    density = gaussian_kde(samples, grid, bandwidth=0.5)

The estimate is ``(1 / n) sum_i N(x; s_i, h^2)``, in 1 / (unit of the samples): it integrates to 1
over the real line. Scott's rule gives ``h = sigma * n^(-1/5)`` (sigma: the sample standard deviation,
ddof = 1). Samples that are all equal (a collapsed prior: every sample in one lane) have sigma = 0;
their bandwidth is ``min_bandwidth``, so the density is a narrow peak rather than a division by zero.
"""

from __future__ import annotations

import numpy as np

from driveopt.errors import DriveoptError


class KDEError(DriveoptError):
    """Samples or bandwidth that no density can be estimated from (empty, non-finite, non-positive)."""


def scott_bandwidth(samples: np.ndarray, min_bandwidth: float) -> float:
    """Scott's rule ``sigma * n^(-1/5)`` [unit of the samples], at least ``min_bandwidth``."""
    samples = np.asarray(samples, np.float64).ravel()
    sigma = float(np.std(samples, ddof=1)) if samples.size > 1 else 0.0
    return max(sigma * samples.size ** (-0.2), float(min_bandwidth))


def gaussian_kde(samples: np.ndarray, grid: np.ndarray, bandwidth: float | None = None, min_bandwidth: float = 0.05) -> np.ndarray:
    """Density (same shape as ``grid``) [1 / unit] of the 1-D ``samples`` (any shape, flattened) at ``grid``.

    bandwidth: kernel standard deviation [unit]; None: :func:`scott_bandwidth` with ``min_bandwidth``.
    """
    samples = np.asarray(samples, np.float64).ravel()
    if samples.size == 0:
        raise KDEError("gaussian_kde needs at least one sample")
    if not np.all(np.isfinite(samples)):
        raise KDEError("gaussian_kde: samples contain NaN or inf")
    if not (np.isfinite(min_bandwidth) and min_bandwidth > 0):
        raise KDEError(f"gaussian_kde: min_bandwidth must be a positive number, got {min_bandwidth!r}")
    h = scott_bandwidth(samples, min_bandwidth) if bandwidth is None else float(bandwidth)
    if not (np.isfinite(h) and h > 0):
        raise KDEError(f"gaussian_kde: bandwidth must be a positive number, got {bandwidth!r}")
    grid = np.asarray(grid, np.float64)
    z = (grid[..., None] - samples) / h
    return np.exp(-0.5 * z**2).sum(axis=-1) / (samples.size * h * np.sqrt(2.0 * np.pi))
