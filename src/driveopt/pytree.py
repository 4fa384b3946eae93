"""Frozen dataclasses that are JAX pytrees: array fields are leaves, configuration fields are static.

The priors and safety filters the planner takes are such dataclasses. A learned one holds its weights and
normaliser as leaves and its network configuration as a static field::

    @pytree_dataclass
    class LearnedFilter:
        params: Any
        normaliser: Any
        config: Any = static()

so ``jax.jit`` traces the weights as inputs and keys its compilation cache on the configuration: two planners
with equal configurations share one compilation whatever their weights, and new weights never recompile.
Static fields must be hashable (frozen dataclasses, tuples, numbers).
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import jax

T = TypeVar("T", bound=type)


def static(default: Any = dataclasses.MISSING) -> Any:
    """A dataclass field that is part of the pytree's structure (hashed into jit's cache key), not a leaf; without
    ``default`` the field is required."""
    return dataclasses.field(default=default, metadata=dict(static=True))


def pytree_dataclass(cls: T) -> T:
    """``cls`` as a frozen dataclass registered with JAX: fields declared with :func:`static` are structure, every
    other field is a leaf (a subtree: arrays, dicts of arrays, another pytree or None)."""
    return jax.tree_util.register_dataclass(dataclasses.dataclass(frozen=True)(cls))
