"""Where the time of one planning call goes: its parts, each jitted and timed on its own.

    python benchmarks/perf/call_profile.py --json out/call-profile.json [--samples 250 1000] [--calls 30]

One call of the default planner (``PlannerConfig`` with ``--samples`` samples, 5 sampler iterations x 20 projection
iterations, the projection's early stop off so that every call does the same work, as ``benchmarks/perf/latency.py``) on
the built-in 10-neighbour problem ``dense-snapshot`` is split into the parts ``driveopt.planner.solve`` chains:

- ``proposal``: the prior's first batch (``prior.propose``), then one Gaussian draw per later iteration
  (``sample_gaussian`` + ``clip_setpoints``);
- ``setpoint_qp``: the appended stop rows and the set-point QP of the batch (``setpoint_batch`` + ``braking_coeffs``);
- ``projection``: the batch projection (``project_batch``);
- ``ranking_update``: trajectories, cost terms, ranking, elite selection and the CEM update (``evaluate``,
  ``cost_terms``, the ranking's ``score``/``key``/``elites``, ``cem_update``);
- ``fallback``: the stop offered as fallback (``Fallback.choose``);
- ``readout``: the host side of ``plan()`` after the compiled call (its copy of a solution not read before,
  ``driveopt.host_copy.to_host``, and the numpy result); ``readout_ms`` times it with the copy forced to one buffer
  per dtype (``packed``) and to one copy per array (``per_array``, ``jax.device_get``).

Each part is jitted separately, with the planner's CPU compiler options and float32 products, and timed as the median
of ``--calls`` calls after its compilation (compile time recorded separately, JAX's persistent compilation cache off);
a part's ``per_call_ms`` is its median times the number of times one planning call runs it. ``whole_ms`` is the
planner's own compiled ``solve`` and ``plan_ms`` the whole ``plan()`` call: the difference between the parts' sum and
``whole_ms`` is what fusing them into one executable saves or costs (dispatches, copies between parts). The machine's
load average (``os.getloadavg``) is recorded before and after. Measurement only: the planner's code is not changed.

The projection's arithmetic is counted too (``benchmarks/perf/op_count.py``: scalar operations of its jaxpr, products and
elementwise apart; the same step run as a fixed-length scan, since a while loop's length is not in its jaxpr), per
run and per planning call, with the rate its measured time implies: what a time target needs is that count over the
target.
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from driveopt.cli.common import positive_int
from driveopt.config import PlannerConfig
from driveopt.costs import COST_TERMS, cost_terms, weighted_cost
from driveopt.experiments.runner import cpu_model
from driveopt.fallback import Fallback, braking_coeffs, stop_setpoints
from driveopt.files import write_json
from driveopt.host_copy import to_host
from driveopt.method import Method
from driveopt.planner import _to_result, compiled_solve, plan, project_batch, setpoint_batch
from driveopt.problem import build_problem
from driveopt.qp import make_model
from driveopt.ranking import FeasibilityFirst
from driveopt.sampler import GaussianPrior, cem_update, clip_setpoints, sample_gaussian
from driveopt.scene import load_scene
from driveopt.trajectory import evaluate
from driveopt.xla import XLA_CPU_COMPILER_OPTIONS, float32_products, supported_compiler_options

if __package__ in (None, ""):  # run as a file: the repository root on the path, for the package import below
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks.perf.op_count import count_operations  # noqa: E402

PROBLEM = "dense-snapshot"
PARTS = ("proposal", "setpoint_qp", "projection", "ranking_update", "fallback", "readout")


def profile_config(samples: int, iterations: int = 5, projection_iterations: int = 20) -> PlannerConfig:
    """The default planner at ``samples`` samples x ``iterations`` x ``projection_iterations``, early stop off."""
    return PlannerConfig().with_samples(samples).replace(sampler={"num_iterations": iterations},
                                                         projection={"max_iterations": projection_iterations,
                                                                     "tolerance": 0.0})


def _jit(fn, static: tuple[str, ...]):
    options = supported_compiler_options(XLA_CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else None
    return jax.jit(float32_products(fn), static_argnames=static, compiler_options=options)


def _proposal_first(problem, key, prior, cfg):
    return prior.propose(problem, key, cfg.sampler.num_samples, None)


def _proposal_next(problem, key, mean, cov, cfg):
    return clip_setpoints(sample_gaussian(key, mean, cov, cfg.sampler.num_samples), problem, cfg.projection.v_max)


def _setpoint_qp(problem, setpoints, cfg, fallback):
    """The rows of one batch (samples, then the comfortable and the emergency stop) through the set-point QP."""
    model = make_model(cfg.basis, cfg.qp)
    stops = fallback.stops(cfg.projection.a_max)
    rows = jnp.concatenate([setpoints, *[stop_setpoints(problem, cfg.basis.horizon, *stop)[None] for stop in stops]])
    coeffs, b_x, b_y = setpoint_batch(model, problem, cfg, rows)
    row = (lambda b, i: b if b.ndim == 1 else b[i])  # per-sample boundary rows: goals only
    for i, (decel, target) in zip(range(-len(stops), 0), stops):
        coeffs = coeffs.at[i].set(braking_coeffs(model, problem, decel, row(b_x, i), row(b_y, i), target))
    return rows, coeffs, b_x, b_y


def _projection(problem, coeffs, b_x, b_y, cfg, unroll=False):
    return project_batch(make_model(cfg.basis, cfg.qp), problem, cfg, coeffs, b_x, b_y, unroll=unroll)


def projection_operations(problem, coeffs, b_x, b_y, cfg: PlannerConfig) -> dict[str, int]:
    """Scalar operations of one run of the projection part on a batch (B, 2n) (``op_count``; they depend on the shapes
    only), counted on its fixed-length (scan) form: the same step, ``max_iterations`` times, as the timed while loop
    runs it with the early stop off."""
    fn = float32_products(functools.partial(_projection, cfg=cfg, unroll=True))
    return count_operations(jax.make_jaxpr(fn)(problem, coeffs, b_x, b_y))


def _ranking_update(problem, rows, projected, residuals, mean, cov, cfg, ranking):
    """Cost, ranking and elite set of one projected batch, the best row, and the CEM update of the Gaussian."""
    s = cfg.sampler
    traj = evaluate(make_model(cfg.basis, cfg.qp), projected)
    terms = cost_terms(traj, problem, None)
    cost = weighted_cost(terms, cfg.cost)
    residual = residuals.total
    score = ranking.score(cost, residual)
    feasible = residual <= s.residual_tolerance
    key = ranking.key(score, residual, feasible)
    elites = ranking.elites(key, residual, score, feasible, s.num_constraint_elites, s.num_elites)
    pick = elites[jnp.argmin(key[elites])]
    term_values = jnp.stack([terms[k] for k in COST_TERMS])
    new_mean, new_cov = cem_update(mean, cov, rows[elites], score[elites], s)
    return elites, pick, term_values[:, pick], new_mean, new_cov


def _fallback(problem, cfg, fallback, ranking):
    return fallback.choose(make_model(cfg.basis, cfg.qp), problem, cfg, ranking)


def _median_ms(fn, calls: int) -> float:
    times = []
    for _ in range(calls):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def _compile_s(jitted, *args, **kwargs) -> float:
    start = time.perf_counter()
    jitted.lower(*args, **kwargs).compile()
    return time.perf_counter() - start


class Pipeline:
    """The jitted parts of one planning call at ``cfg``, their arguments (the first sampler iteration's arrays on
    ``problem``, computed by the parts themselves) and how many times one call runs each."""

    def __init__(self, cfg: PlannerConfig, problem, prior, ranking, fallback, key) -> None:
        self.fns = {"proposal_first": _jit(_proposal_first, ("cfg",)), "proposal_next": _jit(_proposal_next, ("cfg",)),
                    "setpoint_qp": _jit(_setpoint_qp, ("cfg", "fallback")), "projection": _jit(_projection, ("cfg",)),
                    "ranking_update": _jit(_ranking_update, ("cfg", "ranking")),
                    "fallback": _jit(_fallback, ("cfg", "fallback", "ranking"))}
        self.args: dict[str, tuple[tuple, dict]] = {}
        self.compile_s: dict[str, float] = {}  # [s] each part's compilation (lowering included)
        key_prior, key_loop = jax.random.split(key)  # as solve() splits it
        self.proposal = self._first("proposal_first", (problem, key_prior, prior), {"cfg": cfg})
        self._first("proposal_next", (problem, key_loop, self.proposal.mean, self.proposal.cov), {"cfg": cfg})
        self.rows, self.qp_coeffs, b_x, b_y = self._first("setpoint_qp", (problem, self.proposal.samples),
                                                          {"cfg": cfg, "fallback": fallback})
        self.projected = self._first("projection", (problem, self.qp_coeffs, b_x, b_y), {"cfg": cfg})
        self.ranked = self._first("ranking_update", (problem, self.rows, self.projected.coeffs, self.projected.residuals,
                                                     self.proposal.mean, self.proposal.cov), {"cfg": cfg, "ranking": ranking})
        self._first("fallback", (problem,), {"cfg": cfg, "fallback": fallback, "ranking": ranking})
        iterations = cfg.sampler.num_iterations
        self.runs = {"proposal_first": 1, "proposal_next": iterations - 1, "setpoint_qp": iterations,
                     "projection": iterations, "ranking_update": iterations, "fallback": 1}

    def _first(self, name: str, args: tuple, kwargs: dict):
        """Compile part ``name`` for ``args`` (timed), keep the arguments for :meth:`call`, and run it once."""
        self.compile_s[name] = _compile_s(self.fns[name], *args, **kwargs)
        self.args[name] = (args, kwargs)
        return self.call(name)

    def call(self, name: str):
        args, kwargs = self.args[name]
        return self.fns[name](*args, **kwargs)


def profile(samples: int, calls: int, iterations: int = 5, projection_iterations: int = 20) -> dict:
    """The parts of one planning call at ``samples`` samples (see the module docstring)."""
    cfg = profile_config(samples, iterations, projection_iterations)
    scene = load_scene(PROBLEM)
    problem = build_problem(scene, cfg.basis)
    prior, ranking, fallback = GaussianPrior.from_config(cfg.sampler, cfg.projection.v_max), FeasibilityFirst(), Fallback()
    key = jax.random.PRNGKey(0)
    pipeline = Pipeline(cfg, problem, prior, ranking, fallback, key)
    runs, rows, projected = pipeline.runs, pipeline.rows, pipeline.projected
    pieces = {}
    for name in pipeline.fns:
        median = _median_ms(functools.partial(pipeline.call, name), calls)
        pieces[name] = {"median_ms": median, "runs_per_call": runs[name], "per_call_ms": median * runs[name],
                        "compile_s": pipeline.compile_s[name]}

    solve = compiled_solve()
    solve_args = (problem, key, cfg, prior, None, None, None)
    solve_kw = {"method": Method(ranking, fallback)}  # as plan() passes it
    whole_compile_s = _compile_s(solve, *solve_args, **solve_kw)
    whole_ms = _median_ms(lambda: solve(*solve_args, **solve_kw), calls)
    # A solution of its own for each read-out, on the device as plan() reads it: a JAX array keeps its host copy after
    # the first read, so reading one solution again would time no copies
    readout_ms = {}  # plan()'s copy (to_host: packed on an accelerator), and each way forced
    for name, copy in (("plan", to_host), ("packed", functools.partial(to_host, packed=True)), ("per_array", jax.device_get)):
        solutions = iter([jax.block_until_ready(solve(*solve_args, **solve_kw)) for _ in range(calls)])
        readout_ms[name] = _median_ms(lambda: _to_result(copy(next(solutions)), cfg, fallback, 0.0), calls)
    plan(problem, cfg, key=key, prior=prior)  # the same compiled solve: this call only warms plan()'s wrapper
    plan_ms = _median_ms(lambda: plan(problem, cfg, key=key, prior=prior).status, calls)

    parts = {
        "proposal": pieces["proposal_first"]["per_call_ms"] + pieces["proposal_next"]["per_call_ms"],
        "setpoint_qp": pieces["setpoint_qp"]["per_call_ms"],
        "projection": pieces["projection"]["per_call_ms"],
        "ranking_update": pieces["ranking_update"]["per_call_ms"],
        "fallback": pieces["fallback"]["per_call_ms"],
        "readout": readout_ms["plan"],
    }
    compiled_sum = sum(v for k, v in parts.items() if k != "readout")
    operations = projection_operations(*pipeline.args["projection"][0], cfg)
    per_call = {kind: n * runs["projection"] for kind, n in operations.items()}
    return {
        "samples": samples, "sampler_iterations": iterations, "projection_iterations": projection_iterations,
        "projection_iterations_run": int(projected.iterations), "batch_rows": int(rows.shape[0]),
        "neighbours": len(scene.neighbours), "nodes": cfg.basis.num_nodes, "calls": calls,
        "parts_ms": parts, "share_of_parts": {k: v / sum(parts.values()) for k, v in parts.items()},
        "pieces": pieces, "parts_sum_ms": sum(parts.values()), "compiled_parts_sum_ms": compiled_sum,
        "whole_ms": whole_ms, "whole_compile_s": whole_compile_s, "plan_ms": plan_ms,
        "readout_ms": {"packed": readout_ms["packed"], "per_array": readout_ms["per_array"]},
        "compile_s_parts_sum": sum(p["compile_s"] for p in pieces.values()),
        "projection_operations": operations, "projection_operations_per_call": per_call,
        "projection_gops_per_s": per_call["total"] / parts["projection"] / 1e6,
    }


def machine() -> dict:
    return {"platform": platform.platform(), "processor": cpu_model(), "python": platform.python_version(), "cpus": os.cpu_count(),
            "affinity": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
            "jax": jax.__version__, "device": str(jax.devices()[0]),
            "compiler_options": supported_compiler_options(XLA_CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else {}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", default="out/call-profile.json", help="results file")
    parser.add_argument("--samples", type=positive_int, nargs="+", default=[250, 1000], help="samples per sampler iteration")
    parser.add_argument("--calls", type=positive_int, default=30, help="timed calls per part after its compilation (>= 20)")
    parser.add_argument("--iterations", type=positive_int, default=5, help="sampler iterations")
    parser.add_argument("--projection-iterations", type=positive_int, default=20, help="projection iterations")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_compilation_cache", False)  # compile times are compilations, not cache loads
    report = {"machine": machine(), "problem": PROBLEM, "load_before": os.getloadavg(), "results": []}
    for samples in args.samples:
        result = profile(samples, args.calls, args.iterations, args.projection_iterations)
        report["results"].append(result)
        parts = ", ".join(f"{k} {v:.1f}" for k, v in result["parts_ms"].items())
        print(f"{samples} x {args.iterations} x {args.projection_iterations}: {parts} ms; parts {result['parts_sum_ms']:.1f} ms, "
              f"compiled solve {result['whole_ms']:.1f} ms, plan() {result['plan_ms']:.1f} ms (read-out packed "
              f"{result['readout_ms']['packed']:.2f} ms, per array {result['readout_ms']['per_array']:.2f} ms); projection "
              f"{result['projection_operations_per_call']['total'] / 1e9:.2f} G operations per call, "
              f"{result['projection_gops_per_s']:.1f} G/s", flush=True)
    report["load_after"] = os.getloadavg()
    path = write_json(args.json, report)  # strict JSON, whole or not at all
    print(f"wrote {path} (load average {report['load_before'][0]:.2f} before, {report['load_after'][0]:.2f} after)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
