"""The cross-entropy sampler's numerics (P1 Alg. 1, eq. 6): Gaussian draws, elite selection, the update.

Set-points are ``p = (v_1..v_4, y_1..y_4)``: desired speed [m/s] and lateral position [m]
(road frame) for each quarter of the horizon. The first batch of a planning call comes from a
prior (:mod:`driveopt.priors`); later iterations sample the Gaussian ``N(mean, cov)`` that the
first proposal's moments initialise and :func:`cem_update` adapts.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from driveopt.config import SamplerConfig


def sample_gaussian(key: jax.Array, mean: jnp.ndarray, cov: jnp.ndarray, num: int) -> jnp.ndarray:
    """(num, 8) draws of N(mean, cov); cov is symmetrised and floored on its diagonal first."""
    cov = 0.5 * (cov + cov.T) + 1e-6 * jnp.eye(cov.shape[0], dtype=cov.dtype)
    chol = jnp.linalg.cholesky(cov)
    return mean + jax.random.normal(key, (num, mean.shape[0]), mean.dtype) @ chol.T


def select_lowest(values: jnp.ndarray, count: int) -> jnp.ndarray:
    """Indices of the ``count`` smallest values, smallest first."""
    return jax.lax.top_k(-values, count)[1]


def cem_update(
    mean: jnp.ndarray, cov: jnp.ndarray, elites: jnp.ndarray, elite_costs: jnp.ndarray, cfg: SamplerConfig
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """P1 eq. 6 with weights exp(-(c - min c) / temperature) (the minimum is subtracted first)."""
    shifted = elite_costs - jnp.min(elite_costs)
    weights = jnp.exp(-shifted / cfg.temperature)
    weights = weights / jnp.sum(weights)
    new_mean = (1.0 - cfg.learning_rate) * mean + cfg.learning_rate * weights @ elites
    centred = elites - new_mean
    spread = (weights[:, None] * centred).T @ centred
    new_cov = (1.0 - cfg.learning_rate) * cov + cfg.learning_rate * spread
    new_cov = new_cov + cfg.covariance_jitter * jnp.eye(mean.shape[0], dtype=mean.dtype)
    return new_mean, new_cov
