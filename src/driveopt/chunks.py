"""Loops over a number of rows known only at run time, in chunks of sizes fixed at compile time.

A batch whose useful rows are counted inside a compiled call (the distinct prefixes of the PixelCNN's samples, the
distinct rows of a projected batch) keeps its static shape, but its work can follow the count: :func:`over_chunks`
runs a body over chunks of the first size while at least that many rows are left, then of the next, the last size
covering what remains. Large chunks make fewer, larger products; small ones waste fewer rows at the end.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp


def capacity(rows: int, sizes: Sequence[int]) -> int:
    """Rows a buffer needs for :func:`over_chunks` over at most ``rows`` rows: its last chunk may reach past the last
    row, never by a whole chunk."""
    return rows + max(sizes)


def over_chunks(count, sizes: Sequence[int], body: Callable[[int, Any, Any], Any], carry: Any) -> Any:
    """``carry`` after ``body(size, start, carry)`` for chunks that cover rows 0 .. ``count`` - 1 in order: of
    ``sizes[0]`` rows while at least that many are left, then of the next size; the last size covers the rest (its
    last chunk reaching past ``count``). ``count`` may be traced; ``sizes`` are static, largest first. Each size is a
    ``fori_loop`` whose trip count follows ``count`` (not reverse-differentiable)."""
    done = jnp.zeros((), jnp.int32)
    for number, size in enumerate(sizes):
        left = count - done
        chunks = (left + size - 1) // size if number == len(sizes) - 1 else left // size
        carry = jax.lax.fori_loop(0, chunks, lambda c, carry, size=size, done=done: body(size, done + c * size, carry),
                                  carry)
        done = done + chunks * size
    return carry
