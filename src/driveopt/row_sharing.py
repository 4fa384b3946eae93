"""How a batch's identical rows are projected.

A learned prior that draws discrete codes (P2's PixelCNN) gives many samples the same code sequence, and so the same
set-points and the same set-point-QP trajectory: of the 1003 rows of a ``vqvae-filter`` batch on P2's dense traffic,
a median 210 differ (at most 571 in 90 closed-loop states, ``benchmarks/perf/row_sharing_ab.py``). The projection treats
each row on its own, so a repeated row comes out as its first copy does.

:class:`EveryRow` (the default) projects the batch as it is. :class:`DistinctRows` projects each distinct row once, in
chunks (loops whose trip counts follow the number of distinct rows), and gives every row its copy's result: the work
follows the number of distinct rows. Each chunk's projection stops early on its own rows (``projection.tolerance``),
where one projection of the whole batch stops when every row of the batch has settled, so a row's result can differ
from the whole batch's in the iterations it gets, as it would in a smaller batch; and its arithmetic rounds as in a
batch of the chunk's size. Both are frozen dataclasses that :func:`driveopt.planner.solve` takes as a static
argument.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

import jax
import jax.numpy as jnp

from driveopt.checks import check_count, require
from driveopt.chunks import capacity, over_chunks
from driveopt.projection import ProjectionResult, ProjectionStatus, Residuals

ProjectRows = Callable[[jnp.ndarray, jnp.ndarray, jnp.ndarray], ProjectionResult]  # (coeffs (B, 2n), b_x, b_y) -> result


class RowSharing(Protocol):
    def project(self, project_rows: ProjectRows, coeffs: jnp.ndarray, b_x: jnp.ndarray, b_y: jnp.ndarray) -> ProjectionResult:
        """The projection of the batch ``coeffs`` (B, 2n) with boundary values ``b_x``, ``b_y`` ((m,) shared, or (B, m)
        per row), from ``project_rows``, which projects any batch of rows."""
        ...


@dataclass(frozen=True)
class EveryRow:
    """Every row is projected, repeated or not."""

    def project(self, project_rows: ProjectRows, coeffs, b_x, b_y) -> ProjectionResult:
        return project_rows(coeffs, b_x, b_y)


def distinct_rows(rows: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """Groups of bit-for-bit identical rows of ``rows`` (B, D): (one member of each group (B,) indices, the groups
    first and then index 0 as filler; the number of groups; each row's group (B,)).

    Rows are ordered by a hash of their bits and a group is a run of identical neighbours in that order, so a hash
    collision can split a group (a row projected twice), never merge different rows."""
    bits = jax.lax.bitcast_convert_type(rows, jnp.uint32)
    multipliers = (2 * jnp.arange(rows.shape[1], dtype=jnp.uint32) + 1) * jnp.uint32(0x9E3779B1)
    order = jnp.argsort(jnp.sum(bits * multipliers, axis=1, dtype=jnp.uint32), stable=True)
    ordered = bits[order]
    starts = jnp.concatenate([jnp.ones(1, bool), jnp.any(ordered[1:] != ordered[:-1], axis=1)])
    group = jnp.cumsum(starts.astype(jnp.int32)) - 1  # of each row in hash order
    member = jnp.zeros_like(order).at[group].set(order)  # identical rows: any of them
    return member, group[-1] + 1, jnp.zeros_like(group).at[order].set(group)


@dataclass(frozen=True)
class DistinctRows:
    """Each distinct row (with its boundary values) is projected once, in chunks of the sizes ``chunks``
    (:func:`driveopt.chunks.over_chunks`; the last chunk filled up with copies of row 0). Repeated rows read their
    copy's result. The result's ``iterations`` is the most any chunk ran, its
    ``error`` the largest, and its ``status`` CONVERGED only when every chunk converged."""

    chunks: tuple[int, ...] = (256, 64)  # [-] rows per projection, largest first

    def __post_init__(self) -> None:
        object.__setattr__(self, "chunks", tuple(self.chunks))  # hashable: the planner's static argument
        require(len(self.chunks) > 0, "DistinctRows.chunks must name at least one chunk size")
        for size in self.chunks:
            check_count("DistinctRows.chunks", size)

    def project(self, project_rows: ProjectRows, coeffs, b_x, b_y) -> ProjectionResult:
        B = coeffs.shape[0]
        member, count, group = distinct_rows(jnp.concatenate([coeffs, *[b for b in (b_x, b_y) if b.ndim == 2]], axis=1))
        sizes = [min(size, B) for size in self.chunks]
        rows = capacity(B, sizes)
        member = jnp.concatenate([member, jnp.zeros(rows - B, member.dtype)])

        def project_chunk(size: int, start, carry):
            buffers, iterations, status, error = carry
            index = jax.lax.dynamic_slice_in_dim(member, start, size)
            result = project_rows(*(a if a.ndim == 1 else a[index] for a in (coeffs, b_x, b_y)))
            buffers = jax.tree_util.tree_map(lambda buffer, new: jax.lax.dynamic_update_slice_in_dim(buffer, new, start, 0),
                                             buffers, (result.coeffs, result.multipliers, result.residuals))
            return (buffers, jnp.maximum(iterations, result.iterations), jnp.maximum(status, result.status),
                    jnp.maximum(error, result.error))

        def zeros(shape):
            return jnp.zeros(shape, coeffs.dtype)

        empty = (zeros((rows, coeffs.shape[1])), zeros((rows, coeffs.shape[1])), Residuals(*(zeros(rows) for _ in Residuals._fields)))
        (projected, multipliers, residuals), iterations, status, error = over_chunks(
            count, sizes, project_chunk,
            (empty, jnp.zeros((), jnp.int32), jnp.asarray(ProjectionStatus.CONVERGED, jnp.int32), zeros(())))
        return ProjectionResult(projected[group], multipliers[group], jax.tree_util.tree_map(lambda a: a[group], residuals),
                                iterations, status, error)
