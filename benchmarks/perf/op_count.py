"""The arithmetic a traced JAX function does, counted on its jaxpr: a machine-independent measure of a computation's
work, to set a measured time against (operations per second) and to say what rate a time target needs.

    count_operations(jax.make_jaxpr(fn)(*args))

Counting rule (one operation = one scalar result of one primitive):
- a matrix product (``dot_general``) counts a multiply and an add per term: 2 x (output elements) x (contracted size);
- a reduction counts one per input element; a sort n log2 n per sorted row;
- ``lu`` 2/3 m^3 and ``triangular_solve`` m^2 per right-hand side, per matrix;
- data movement (reshapes, slices, broadcasts, concatenation, gathers, casts, bit casts) counts nothing;
- every other primitive is elementwise: one per output element, whatever it computes (a square root or a divide counts
  as one, as an add does);
- a ``scan`` counts its body times its length, a ``cond`` its costliest branch, calls (``jit``, custom derivatives and
  batching rules, ``custom_linear_solve``) what they run. A ``while_loop`` runs an unknown number of times: it is
  refused (count a fixed-length ``scan`` version instead).
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
from jax.extend.core import ClosedJaxpr, Jaxpr

MOVEMENT = frozenset({
    "broadcast_in_dim", "concatenate", "convert_element_type", "gather", "iota", "pad", "reshape", "slice", "squeeze",
    "stack", "transpose", "bitcast_convert_type", "stop_gradient", "copy", "copy_p", "dynamic_slice",
    "dynamic_update_slice", "rev", "expand_dims", "split",
})
REDUCTIONS = frozenset({"reduce_sum", "reduce_max", "reduce_min", "reduce_prod", "reduce_and", "reduce_or", "argmin",
                        "argmax", "cumsum", "cummax", "cummin"})


def _size(var) -> int:
    return int(np.prod(var.aval.shape, dtype=np.int64))


def _inner(params: dict) -> list[Jaxpr]:
    """The jaxprs a call-like primitive runs (every jaxpr among its parameters)."""
    found = []
    for value in params.values():
        for item in value if isinstance(value, (tuple, list)) else [value]:
            if isinstance(item, ClosedJaxpr):
                found.append(item.jaxpr)
            elif isinstance(item, Jaxpr):
                found.append(item)
    return found


def _scaled(counts: Counter, factor: int) -> Counter:
    return Counter({kind: factor * n for kind, n in counts.items()})


def _equation(eqn) -> Counter:
    """Operations of one equation by kind: products, reductions, sorts, factorisations, elementwise."""
    name, params = eqn.primitive.name, eqn.params
    if name == "while":
        raise ValueError("a while_loop runs an unknown number of times: count a fixed-length scan version")
    if name == "scan":
        return _scaled(_count(params["jaxpr"].jaxpr), params["length"])
    if name == "cond":
        return max((_count(branch.jaxpr) for branch in params["branches"]), key=lambda c: c.total())
    if name == "custom_linear_solve":  # runs its solve; the matvec and transposes only serve differentiation
        return _count(params["jaxprs"].solve.jaxpr)
    inner = _inner(params)
    if inner:
        if name.startswith("custom_vjp") or name.startswith("custom_jvp"):
            inner = inner[:1]  # the primal function; the others are derivative rules
        return sum((_count(jaxpr) for jaxpr in inner), Counter())
    if name in MOVEMENT:
        return Counter()
    if name == "dot_general":
        (contract_lhs, _), _ = params["dimension_numbers"]
        lhs = eqn.invars[0].aval.shape
        return Counter(products=2 * _size(eqn.outvars[0]) * int(np.prod([lhs[d] for d in contract_lhs], dtype=np.int64)))
    if name in REDUCTIONS:
        return Counter(reductions=sum(_size(v) for v in eqn.invars))
    if name == "sort":
        shape = eqn.invars[0].aval.shape
        return Counter(sorts=_size(eqn.invars[0]) * max(1, math.ceil(math.log2(max(shape[-1], 2)))))
    if name == "lu":
        shape = eqn.invars[0].aval.shape
        return Counter(factorisations=int(np.prod(shape[:-2], dtype=np.int64)) * (2 * min(shape[-2:]) ** 3) // 3)
    if name == "triangular_solve":
        a, b = (v.aval.shape for v in eqn.invars)
        return Counter(factorisations=int(np.prod(b, dtype=np.int64)) * a[-1])
    return Counter(elementwise=sum(_size(v) for v in eqn.outvars))


def _count(jaxpr: Jaxpr) -> Counter:
    return sum((_equation(eqn) for eqn in jaxpr.eqns), Counter())


def count_operations(closed: ClosedJaxpr) -> dict[str, int]:
    """Scalar operations of one evaluation of ``closed`` (``jax.make_jaxpr(fn)(*args)``) by the rule above, per kind
    (``products``, ``elementwise``, ``reductions``, ``sorts``, ``factorisations``; kinds that do not occur are left
    out) and in all (``total``)."""
    counts = _count(closed.jaxpr)
    return {**{kind: int(n) for kind, n in sorted(counts.items())}, "total": int(counts.total())}
