"""Safeguarded type-II Anderson acceleration of a fixed-point iteration x <- G(x), one independent problem per row of
a batch, with static shapes (for ``jax.lax`` loops).

A row's memory holds up to m differences of its last accepted iterates' residuals r = G(x) - x (``d_residual``) and of
their images G(x) (``d_image``). The next point is the image of the last accepted iterate minus the image differences
weighted by the least-squares fit of its residual by the residual differences (Walker and Ni 2011; Zhang, Peng, Ouyang
and Deng, "Accelerating ADMM for efficient simulation and optimization", TOG 2019):

    gamma = argmin |r - dR gamma|^2 + reg |dR|_F^2 |gamma|^2,    x_next = G(x) - dG gamma

The normal equations (m x m, m <= 8) are solved by elimination without pivoting, one vectorised pass per step over the
batch: the regularised Gram matrix of the differences that take part is symmetric positive definite, so no pivot is
zero, and a slot that holds nothing (or a zero difference) gets a zero weight. The caller evaluates G at the accelerated point, keeps it only where it does no worse
than the accepted iterate by the caller's measure (the safeguard; the projection's is its constraint residual), and
otherwise takes the plain image and empties that row's memory (:func:`remember`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

REGULARISATION = 1e-6  # [-] Tikhonov weight of the least-squares fit, relative to the trace of its Gram matrix
_EMPTY = 1e-12  # a difference of squared length at most this is left out of the fit (nothing to extrapolate from)


class Memory(NamedTuple):
    """Per-row differences in m slots, written in turn (the slot is the same for every row); which slots hold a
    difference of a row's current history is ``valid``, so a restart touches no (m, B, D) array."""

    d_residual: jnp.ndarray  # (m, B, D)
    d_image: jnp.ndarray  # (m, B, D)
    gram: jnp.ndarray  # (B, m, m) inner products of the residual differences
    valid: jnp.ndarray  # (B, m) bool


def empty(window: int, batch: int, dim: int, dtype) -> Memory:
    zeros = jnp.zeros((window, batch, dim), dtype)
    return Memory(zeros, zeros, jnp.zeros((batch, window, window), dtype), jnp.zeros((batch, window), bool))


def remember(memory: Memory, slot, add: jnp.ndarray, keep: jnp.ndarray, d_residual: jnp.ndarray,
             d_image: jnp.ndarray) -> Memory:
    """Write one difference pair (B, D) into ``slot`` (a scalar, the same for every row) of the rows where ``add``;
    rows where ``keep`` is False forget their whole memory (a restart). ``add`` implies ``keep``."""
    d_residual = jnp.where(add[:, None], d_residual, 0.0)  # nothing (not even a NaN) where nothing is added
    d_image = jnp.where(add[:, None], d_image, 0.0)
    d_r = jax.lax.dynamic_update_index_in_dim(memory.d_residual, d_residual, slot, 0)
    d_g = jax.lax.dynamic_update_index_in_dim(memory.d_image, d_image, slot, 0)
    window = d_r.shape[0]
    dots = jnp.stack([jnp.sum(d_r[i] * d_residual, axis=-1) for i in range(window)], axis=-1)  # (B, m)
    at_slot = jnp.arange(window) == slot
    gram = jnp.where(at_slot[None, :, None], dots[:, None, :], memory.gram)
    gram = jnp.where(at_slot[None, None, :], dots[:, :, None], gram)
    valid = jnp.where(at_slot[None, :], add[:, None], memory.valid & keep[:, None])
    return Memory(d_r, d_g, gram, valid)


def extrapolate(memory: Memory, residual: jnp.ndarray, image: jnp.ndarray,
                regularisation: float = REGULARISATION) -> jnp.ndarray:
    """The accelerated point (B, D) from the accepted iterate's ``residual`` G(x) - x and ``image`` G(x) (B, D); the
    image itself where the memory is empty."""
    m = memory.d_residual.shape[0]
    # A slot takes part where it holds a difference of this row's history that is not (numerically) zero; the others
    # get the equation 1 * w = 0, so that no pivot is tiny (nor its derivative, through an unrolled loop, infinite).
    used = memory.valid & (memory.gram[:, jnp.arange(m), jnp.arange(m)] > _EMPTY)
    v = used.astype(residual.dtype)  # (B, m)
    gram = [[memory.gram[:, i, j] * v[:, i] * v[:, j] for j in range(m)] for i in range(m)]  # (B,) entries
    shift = regularisation * sum(gram[i][i] for i in range(m))
    for i in range(m):
        gram[i][i] = jnp.where(used[:, i], gram[i][i] + shift, 1.0)
    rhs = [v[:, i] * jnp.sum(memory.d_residual[i] * residual, axis=-1) for i in range(m)]
    weights = solve_spd(gram, rhs)
    return image - sum(w[:, None] * memory.d_image[i] for i, w in enumerate(weights))


def solve_spd(matrix: list[list[jnp.ndarray]], rhs: list[jnp.ndarray]) -> list[jnp.ndarray]:
    """Solve m x m symmetric positive definite systems given entry by entry (lists of (B,) arrays, one system per row
    of the batch) by Gaussian elimination without pivoting (static m: every operation is elementwise over the batch)."""
    a = [list(row) for row in matrix]
    b = list(rhs)
    m = len(b)
    for k in range(m):
        inv = 1.0 / a[k][k]
        for i in range(k + 1, m):
            factor = a[i][k] * inv
            for j in range(k + 1, m):
                a[i][j] = a[i][j] - factor * a[k][j]
            b[i] = b[i] - factor * b[k]
    x = [None] * m
    for k in reversed(range(m)):
        x[k] = (b[k] - sum(a[k][j] * x[j] for j in range(k + 1, m))) / a[k][k]
    return x
