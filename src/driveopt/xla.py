"""How the planner's computations are compiled: float32 matrix products on every backend, CPU compiler options, and
JAX's persistent compilation cache (:mod:`driveopt.compilation_cache`, set up when this module is imported).

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
import jax.numpy as jnp

from driveopt.compilation_cache import enable_default

enable_default()  # before anything of driveopt's is compiled: the persistent cache (driveopt.compilation_cache)

F = TypeVar("F", bound=Callable)


def float32_products(fn: F) -> F:
    """``fn`` traced with float32 matrix products (``jax.default_matmul_precision("float32")``), also when it is
    called inside another function's trace (a jitted planner, a training step)."""

    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        with jax.default_matmul_precision("float32"):
            return fn(*args, **kwargs)

    return wrapped  # type: ignore[return-value]


# Compiler options for the jit that runs the projection on CPU (jax.jit(..., compiler_options=...)); per-jit
# settings rather than XLA_FLAGS, so nothing else in the user's process changes. Each one only changes how
# the same HLO is emitted, never the maths:
# - 512-bit vectors: the projection is arithmetic-bound in its elementwise loops; ~10% of a planning call
#   on AVX-512 machines (LLVM treats the width as a preference, so other CPUs are unaffected).
# - no YNNPACK fusions: recent jaxlibs hand dots and elementwise/reduce fusions to the YNNPACK library. For
#   this problem's small (B, K) arrays its fusions are much slower than XLA's own loops: the per-sample
#   residual sums alone took ~3 ms of each sampler iteration. 250 x 5 x 20 goes from ~57 to ~48 ms.
XLA_CPU_COMPILER_OPTIONS = {"xla_cpu_prefer_vector_width": 512, "xla_cpu_experimental_ynn_fusion_type": ""}


def supported_compiler_options(options: dict) -> dict:
    """The entries of ``options`` that this jaxlib's compiler accepts (an unknown name is an error at
    compile time, and option names come and go between releases)."""
    supported = {}
    for name, value in options.items():
        try:
            jax.jit(lambda x: x + 1, compiler_options={name: value}).lower(jnp.float32(0)).compile()
        except Exception:  # jaxlib's error type has moved between releases; any failure means "not supported"
            continue
        supported[name] = value
    return supported
