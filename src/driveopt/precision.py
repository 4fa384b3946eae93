"""Float32 matrix products on every backend.

Accelerators multiply float32 matrices at reduced precision by default (TF32 on NVIDIA GPUs, bfloat16 on
TPUs), which is fine for network layers but not for the optimisation layers: the projection's fixed-point
iterations and the set-point QP lose their accuracy, so the same samples end less often feasible and
anything trained through them (the learned safety filter) learns that other solver. The CPU multiplies at
full float32 whatever the setting, so results there are unchanged.
"""
from __future__ import annotations

import functools
from typing import Callable, TypeVar

import jax

F = TypeVar("F", bound=Callable)


def float32_products(fn: F) -> F:
    """``fn`` traced with float32 matrix products (``jax.default_matmul_precision("float32")``), also when it is
    called inside another function's trace (a jitted planner, a training step)."""

    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        with jax.default_matmul_precision("float32"):
            return fn(*args, **kwargs)

    return wrapped  # type: ignore[return-value]
