"""The projection plain and accelerated (``projection.anderson_window``, ``projection.relaxation``): constraint residuals
after k iterations, the iterations the accelerated loop needs to reach the plain loop's residual, time per call.

    python benchmarks/perf/projection_acceleration.py --json out/projection-acceleration.json [--samples 250 1000]
        [--window 4] [--relaxation 1.0] [--iterations 1 2 5 10 15 20 30 40] [--reference 20] [--calls 15]

For each built-in problem (``src/driveopt/problems``) and each batch size ``--samples``: one batch of set-point-QP
trajectories from random set-points (speeds 16 +- 4 m/s, lateral set-points 6 +- 4 m, seed 0, as
``projection_split.py``), projected with the default planner's projection (``PlannerConfig().projection``; early stop
off, so every call runs its iterations; the planner's CPU compiler options) plainly and with the acceleration
(``--window``, ``--relaxation``). Recorded:

- ``residuals``: median and p90 over the batch of the constraint residual (``Residuals.total``, per sample the sum of
  its four families' distances) after each of ``--iterations`` iterations, both ways;
- ``accelerated_medians``: the accelerated batch's median after each of 1 .. ``--reference`` iterations;
- ``to_reach``: the fewest iterations from which on (up to ``--reference``) the accelerated batch's median is at most
  the plain batch's median after ``--reference`` iterations (null: not reached);
- ``timing``: milliseconds per projection call of ``--reference`` iterations both ways, the median of ``--calls``
  calls each after its compilation, the two sides alternating call by call (the machine's other load falls on both).

Every iteration count is its own compilation (the count is static), shared by the problems (jitted with the problem as
an argument). Measurement only; the planner's defaults are not changed. No recorded closed-loop states are read: none
are stored in the repository (benchmarks/results holds outcomes, not planning problems).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from driveopt.cli.common import positive_int
from driveopt.config import PlannerConfig
from driveopt.files import write_json
from driveopt.planner import setpoint_batch
from driveopt.problem import build_problem
from driveopt.projection import project
from driveopt.qp import make_model
from driveopt.scene import load_scene
from driveopt.xla import XLA_CPU_COMPILER_OPTIONS, supported_compiler_options

if __package__ in (None, ""):  # run as a file: the repository root on the path, for the package import below
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks.perf.call_profile import machine  # noqa: E402

PROBLEMS = ("dense-snapshot", "slow-leader-four-lane", "slow-leader-three-lane", "static-blockage")


def batch(model, config: PlannerConfig, name: str, samples: int):
    problem = build_problem(load_scene(name), config.basis)
    key = jax.random.PRNGKey(0)
    setpoints = jnp.concatenate([16 + 4 * jax.random.normal(key, (samples, 4)),
                                 6 + 4 * jax.random.normal(jax.random.fold_in(key, 1), (samples, 4))], 1)
    coeffs, b_x, b_y = setpoint_batch(model, problem, config, setpoints)
    b_x, b_y = (jnp.broadcast_to(b, (samples, b.shape[-1])) for b in (b_x, b_y))
    return problem, coeffs, b_x, b_y


def stats(total) -> dict:
    total = np.asarray(total)
    return {"median": round(float(np.median(total)), 4), "p90": round(float(np.percentile(total, 90)), 4),
            "nonfinite": int(np.sum(~np.isfinite(total)))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", type=Path, required=True, help="results file (written after every batch size)")
    parser.add_argument("--samples", type=positive_int, nargs="+", default=[250, 1000], help="batch sizes")
    parser.add_argument("--window", type=int, default=4, help="projection.anderson_window of the accelerated side")
    parser.add_argument("--relaxation", type=float, default=1.0, help="projection.relaxation of the accelerated side")
    parser.add_argument("--iterations", type=positive_int, nargs="+", default=[1, 2, 5, 10, 15, 20, 30, 40],
                        help="iteration counts at which residuals are recorded")
    parser.add_argument("--reference", type=positive_int, default=20, help="the plain loop's iteration count to match")
    parser.add_argument("--calls", type=positive_int, default=15, help="timed calls per side")
    parser.add_argument("--problems", nargs="+", default=list(PROBLEMS), help="built-in problems")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_compilation_cache", False)

    config = PlannerConfig()
    model = make_model(config.basis, config.qp)
    plain_cfg = dataclasses.replace(config.projection, tolerance=0.0)
    fast_cfg = dataclasses.replace(plain_cfg, anderson_window=args.window, relaxation=args.relaxation)
    compiled = {}
    options = supported_compiler_options(XLA_CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else {}

    def run(cfg, iterations, data):
        key = (cfg, iterations)
        if key not in compiled:
            c = dataclasses.replace(cfg, max_iterations=iterations)
            compiled[key] = jax.jit(lambda problem, t, bx, by: project(model, problem, t, bx, by, c),
                                    compiler_options=options)
        return compiled[key](*data)

    record = {"arguments": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
              "machine": machine(), "load_before": os.getloadavg(), "projection": dataclasses.asdict(plain_cfg),
              "cases": []}
    for samples in args.samples:
        data = {name: batch(model, config, name, samples) for name in args.problems}
        for name, d in data.items():
            case = {"problem": name, "samples": samples, "residuals": []}
            for k in sorted(set(args.iterations) | {args.reference}):
                plain, fast = (run(c, k, d).residuals.total for c in (plain_cfg, fast_cfg))
                case["residuals"].append({"iterations": k, "plain": stats(plain), "accelerated": stats(fast)})
            target = next(r["plain"]["median"] for r in case["residuals"] if r["iterations"] == args.reference)
            medians = [float(np.median(np.asarray(run(fast_cfg, k, d).residuals.total))) for k in range(1, args.reference + 1)]
            case["accelerated_medians"] = [round(m, 4) for m in medians]  # after 1 .. --reference iterations
            # the first count from which the accelerated median stays at or below the target (the medians are not monotone)
            case["to_reach"] = next((k for k in range(1, args.reference + 1) if max(medians[k - 1:]) <= target), None)
            times = {"plain": [], "accelerated": []}
            for side, cfg in (("plain", plain_cfg), ("accelerated", fast_cfg)):
                run(cfg, args.reference, d).coeffs.block_until_ready()
            for _ in range(args.calls):
                for side, cfg in (("plain", plain_cfg), ("accelerated", fast_cfg)):
                    start = time.perf_counter()
                    run(cfg, args.reference, d).coeffs.block_until_ready()
                    times[side].append(time.perf_counter() - start)
            case["timing_ms"] = {side: round(1e3 * float(np.median(t)), 3) for side, t in times.items()}
            case["load"] = os.getloadavg()
            record["cases"].append(case)
            r = {x["iterations"]: x for x in case["residuals"]}[args.reference]
            print(f"{samples:5d} {name:24s} k={args.reference}: plain {r['plain']['median']:.3f}/{r['plain']['p90']:.3f}, "
                  f"accelerated {r['accelerated']['median']:.3f}/{r['accelerated']['p90']:.3f}; reached at "
                  f"{case['to_reach']}; {case['timing_ms']['plain']:.2f} ms vs {case['timing_ms']['accelerated']:.2f} ms, "
                  f"load {case['load'][0]:.2f}", flush=True)
            write_json(args.json, record)
    record["load_after"] = os.getloadavg()
    write_json(args.json, record)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
