"""A hook the signal tests' child processes share: a call when XLA starts compiling the planner."""

from __future__ import annotations

from typing import Callable


def on_planner_compilation(mark: Callable[[], None]) -> None:
    """Call ``mark()`` when XLA starts compiling the planner (``jit_solve``, the long compilation of a first call)."""
    from jax._src import compiler
    from jax._src.lib.mlir import ir

    compile_module = compiler.backend_compile_and_load

    def marked(backend, module, *args, **kwargs):
        if ir.StringAttr(module.operation.attributes["sym_name"]).value == "jit_solve":
            mark()
        return compile_module(backend, module, *args, **kwargs)

    compiler.backend_compile_and_load = marked
