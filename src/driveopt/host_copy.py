"""Copying a compiled call's result to the host in a few buffers instead of one per array.

A planning call's result is a pytree of about 60 small arrays. ``jax.device_get`` copies each on its own; on an
accelerator every copy is a transfer with its own latency (on an H200 the 62 copies were most of the 6 ms between a
1000-sample call's compiled solve, 7.1 ms, and its ``plan()``, 13.3 ms: docs/results/speed.md). :func:`to_host`
concatenates the arrays of each dtype on the device (one small jitted function, compiled once per result structure)
and copies those few buffers, then splits them back on the host into views of the right shapes. On the CPU a copy is a pointer and the concatenation would cost more than it saves, so
there it is ``jax.device_get``. Either way the values are the same bits.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np


def to_host(tree: Any, packed: bool | None = None) -> Any:
    """numpy copy of ``tree`` (a pytree of JAX arrays), as ``jax.device_get`` returns it.

    packed: copy one buffer per dtype (True), each array on its own (False), or choose by the arrays' platform (None:
        packed unless they are on the CPU). Leaves that are not arrays of a numpy dtype (PRNG keys, Python values)
        are copied on their own.
    """
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    arrays = [i for i, leaf in enumerate(leaves) if isinstance(leaf, jax.Array) and _packable(leaf.dtype)]
    if packed is None:
        packed = any(device.platform != "cpu" for i in arrays for device in leaves[i].devices())
    if not packed or len(arrays) < 2:
        return jax.device_get(tree)
    chosen = tuple(leaves[i] for i in arrays)
    unpacked = dict(zip(arrays, _unpack(jax.device_get(_pack(chosen)), [(a.shape, np.dtype(a.dtype)) for a in chosen])))
    return jax.tree_util.tree_unflatten(treedef, [unpacked[i] if i in unpacked else jax.device_get(leaf)
                                                  for i, leaf in enumerate(leaves)])


def _packable(dtype) -> bool:
    try:
        return np.dtype(dtype).kind in "biuf"
    except TypeError:  # extended dtypes (typed PRNG keys)
        return False


def _groups(dtypes: list[np.dtype]) -> list[np.dtype]:
    """The distinct dtypes, in the order they first appear."""
    return list(dict.fromkeys(dtypes))


@jax.jit
def _pack(arrays: tuple[jax.Array, ...]) -> tuple[jax.Array, ...]:
    """One flat array per dtype: the arrays of that dtype raveled and concatenated in their order."""
    dtypes = [np.dtype(a.dtype) for a in arrays]
    return tuple(jnp.concatenate([a.ravel() for a, d in zip(arrays, dtypes) if d == dtype]) for dtype in _groups(dtypes))


def _unpack(buffers: tuple[np.ndarray, ...], layout: list[tuple[tuple[int, ...], np.dtype]]) -> list[np.ndarray]:
    """The arrays :func:`_pack` concatenated, as views of ``buffers`` with their shapes (layout: shape and dtype of
    each, in order)."""
    dtypes = [d for _, d in layout]
    offsets = dict.fromkeys(_groups(dtypes), 0)
    buffer_of = dict(zip(_groups(dtypes), buffers))
    out = []
    for shape, dtype in layout:
        size = int(np.prod(shape, dtype=np.int64))
        start = offsets[dtype]
        out.append(buffer_of[dtype][start:start + size].reshape(shape))
        offsets[dtype] = start + size
    return out
