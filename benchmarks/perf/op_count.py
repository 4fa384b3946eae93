"""The arithmetic a traced JAX function does, counted on its jaxpr: a machine-independent measure of a computation's
work, to set a measured time against (operations per second) and to say what rate a time target needs.

    count_operations(jax.make_jaxpr(fn)(*args))

From the command line, the planner's projection part as ``call_profile.py`` counts it (``dense-snapshot``, the
default planner at ``--samples`` x ``--iterations`` x ``--projection-iterations``, early stop off), plainly and with
projection settings changed (``--set FIELD=VALUE``, repeatable; nothing is timed or compiled):

    python benchmarks/perf/op_count.py --set derivative_bounds=control_points [--samples 250] [--json OUT]

With ``--set early_iterations=K`` every sampler iteration but the last counts a run of K iterations.

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

import argparse
import json
import math
import sys
from collections import Counter
from pathlib import Path

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


def _setting(text: str) -> tuple[str, object]:
    """FIELD=VALUE, the value read as JSON where it parses (numbers, true/false), else as a string."""
    name, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected FIELD=VALUE, got {text!r}")
    try:
        return name, json.loads(value)
    except json.JSONDecodeError:
        return name, value


def projection_counts(samples: int, iterations: int, projection_iterations: int, settings: dict) -> dict:
    """Operations of the projection part of one planning call at ``samples`` x ``iterations`` x ``projection_iterations``
    with the projection fields ``settings`` changed: per run, per planning call and per batch row and iteration."""
    import jax.numpy as jnp  # noqa: PLC0415 (the counting above needs no planner)

    from benchmarks.perf.call_profile import PROBLEM, _setpoint_qp, profile_config, projection_operations  # noqa: PLC0415
    from driveopt.fallback import Fallback  # noqa: PLC0415
    from driveopt.problem import build_problem  # noqa: PLC0415
    from driveopt.scene import load_scene  # noqa: PLC0415

    cfg = profile_config(samples, iterations, projection_iterations).replace(projection=settings)
    problem = build_problem(load_scene(PROBLEM), cfg.basis)
    setpoints = jnp.concatenate([jnp.full((samples, 4), 16.0), jnp.full((samples, 4), 6.0)], axis=1)  # shapes only
    rows, coeffs, b_x, b_y = _setpoint_qp(problem, setpoints, cfg, Fallback())
    per_run = projection_operations(problem, coeffs, b_x, b_y, cfg.replace(projection={"early_iterations": 0}))
    longer = projection_operations(problem, coeffs, b_x, b_y, cfg.replace(
        projection={"max_iterations": projection_iterations + 1, "early_iterations": 0}))
    early = cfg.projection.earlier_iterations  # the runs of every sampler iteration but the last
    per_early_run = per_run if early == cfg.projection.max_iterations else projection_operations(
        problem, coeffs, b_x, b_y, cfg.replace(projection={"max_iterations": early, "early_iterations": 0}))
    batch_rows = int(rows.shape[0])
    return {"settings": settings, "batch_rows": batch_rows, "per_run": per_run,
            "per_call": {kind: n + per_early_run.get(kind, 0) * (iterations - 1) for kind, n in per_run.items()},
            # one more iteration's operations (the loop's body) over the rows; the rest of a run is its set-up (the KKT
            # inverses, the first evaluation) and the residuals of its result
            "per_row_and_iteration": {kind: (longer.get(kind, 0) - n) / batch_rows for kind, n in per_run.items()}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=250, help="samples per sampler iteration")
    parser.add_argument("--iterations", type=int, default=5, help="sampler iterations")
    parser.add_argument("--projection-iterations", type=int, default=20, help="projection iterations")
    parser.add_argument("--set", type=_setting, action="append", default=[], metavar="FIELD=VALUE",
                        help="a projection field of the compared side (repeatable)")
    parser.add_argument("--json", type=Path, help="results file")
    args = parser.parse_args(argv)
    shape = (args.samples, args.iterations, args.projection_iterations)
    sides = {"plain": projection_counts(*shape, {})}
    if args.set:
        sides["changed"] = projection_counts(*shape, dict(args.set))
    for name, side in sides.items():
        per_row = side["per_row_and_iteration"]
        print(f"{name} {side['settings']}: {side['per_call']['total'] / 1e9:.3f} G operations per call, per row and "
              f"iteration {per_row['total'] / 1e3:.1f} k ({per_row.get('products', 0) / 1e3:.1f} k in products, "
              f"{per_row.get('elementwise', 0) / 1e3:.1f} k elementwise)")
    if args.json:
        from driveopt.files import write_json  # noqa: PLC0415

        write_json(args.json, {"command": "python benchmarks/perf/op_count.py " + " ".join(argv or sys.argv[1:]),
                               "problem": "dense-snapshot", "samples": args.samples, "iterations": args.iterations,
                               "projection_iterations": args.projection_iterations, **sides})
    return 0


if __name__ == "__main__":
    if __package__ in (None, ""):  # run as a file: the repository root on the path, for the package imports
        sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    raise SystemExit(main())
