"""Where the real-time projection's time goes: variants of it, timed against it in alternating rounds.

    python benchmarks/perf/projection_variants.py --json out/projection-variants.json [--samples 250 1000] [--rounds 30]
        [--variants realtime obstacle-stride-4 ...]

The projection of ``bilevel`` (``driveopt.registry.REALTIME_PROJECTION``, early stop off so that every call does the
same work) on the built-in 10-neighbour problem ``dense-snapshot``, for one batch of ``--samples`` set-point-QP
trajectories (speeds the ego's +- 4 m/s, random lanes), and the same call with one thing changed:

- ``realtime``: as ``bilevel`` projects;
- ``batch-nearest-4``, ``batch-nearest-5``: rows of only the 4 (5) neighbours nearest any sample at each node
  (``nearest_choice="batch"``);
- ``sample-nearest-4``: rows of only each sample's own 4 nearest neighbours at each node;
- ``4-slots``, ``1-slot``: the problem built with room for only 4 (1) neighbours (``build_problem``'s
  ``max_obstacles``): what the neighbours' terms cost in the loops;
- ``obstacle-stride-4``: obstacle rows at every node over the first 3 s, then at every 4th (``obstacle_stride``);
- ``no-anderson``: the same 12 iterations without Anderson's window (its safeguard's residuals and fit);
- ``plain-nodes``: 12 plain iterations with the speed and acceleration rows at the nodes;
- ``no-iterations``: none (the per-call set-up and the final residuals).

Every variant is jitted once with the planner's compiler options (compiled before timing), then each round calls every variant once, in turn, so that the
machine's load falls alike on all; the median over ``--rounds`` rounds is recorded with the batch's median residual.
The machine and its load average (before and after) are recorded. Measurement only: the planner's code is not changed.
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
from driveopt.config import ProjectionConfig, QPConfig
from driveopt.files import write_json
from driveopt.problem import build_problem
from driveopt.projection import project
from driveopt.qp import boundary_values, make_model, solve_setpoint_qp
from driveopt.registry import REALTIME_PROJECTION
from driveopt.scene import load_scene
from driveopt.xla import XLA_CPU_COMPILER_OPTIONS, supported_compiler_options

if __package__ in (None, ""):  # run as a file: the repository root on the path, for the package import below
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks.perf.call_profile import machine  # noqa: E402

REALTIME = dataclasses.replace(ProjectionConfig(), **{**REALTIME_PROJECTION, "early_iterations": 0}, tolerance=0.0)  # one
# projection of its max_iterations: early_iterations counts those of the sampler's earlier iterations
VARIANTS = {  # name: (neighbour slots of the problem, projection configuration)
    "realtime": (10, REALTIME),
    "batch-nearest-4": (10, dataclasses.replace(REALTIME, nearest_obstacles=4, nearest_choice="batch")),
    "batch-nearest-5": (10, dataclasses.replace(REALTIME, nearest_obstacles=5, nearest_choice="batch")),
    "sample-nearest-4": (10, dataclasses.replace(REALTIME, nearest_obstacles=4)),
    "obstacle-stride-4": (10, dataclasses.replace(REALTIME, obstacle_stride=4)),
    "4-slots": (4, REALTIME),
    "1-slot": (1, REALTIME),
    "no-anderson": (10, dataclasses.replace(REALTIME, anderson_window=0)),
    "plain-nodes": (10, dataclasses.replace(REALTIME, anderson_window=0, derivative_bounds="nodes")),
    "no-iterations": (10, dataclasses.replace(REALTIME, max_iterations=0)),
}


def batch(samples: int, slots: int):
    """(problem, targets (B, 2n), b_x, b_y) on dense-snapshot with ``slots`` neighbour slots; the same set-points for
    every slot count."""
    model = make_model()
    problem = build_problem(load_scene("dense-snapshot"), max_obstacles=slots)
    key = jax.random.PRNGKey(samples)
    speeds = jnp.clip(problem.init_x[1] + 4 * jax.random.normal(key, (samples, 4)), 0.0, 30.0)
    lanes = problem.lane_center0 + problem.lane_width * jax.random.randint(jax.random.fold_in(key, 1), (samples, 4), 0,
                                                                           int(problem.num_lanes))
    b_x, b_y = boundary_values(problem.init_x, problem.init_y, QPConfig())
    return problem, solve_setpoint_qp(model, jnp.concatenate([speeds, lanes], 1), b_x, b_y), b_x, b_y


def measure(samples: int, rounds: int, variants) -> dict:
    model = make_model()
    options = supported_compiler_options(XLA_CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else None
    calls = {}
    for name in variants:
        slots, cfg = VARIANTS[name]
        problem, target, b_x, b_y = batch(samples, slots)
        run = jax.jit(lambda t, p=problem, bx=b_x, by=b_y, c=cfg: project(model, p, t, bx, by, c),
                      compiler_options=options)
        start = time.perf_counter()
        out = run(target)
        out.coeffs.block_until_ready()
        calls[name] = (run, target, time.perf_counter() - start, float(np.median(np.asarray(out.residuals.total))))
    times = {name: [] for name in calls}
    for _ in range(rounds):
        for name, (run, target, _, _) in calls.items():
            start = time.perf_counter()
            run(target).coeffs.block_until_ready()
            times[name].append(time.perf_counter() - start)
    return {name: {"median_ms": 1e3 * float(np.median(times[name])), "p90_ms": 1e3 * float(np.percentile(times[name], 90)),
                   "first_call_s": first, "median_residual": residual}
            for name, (_, _, first, residual) in calls.items()}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="projection_variants.py", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", type=Path, required=True, help="results file (written after every batch size)")
    parser.add_argument("--samples", type=positive_int, nargs="+", default=[250, 1000], help="batch sizes")
    parser.add_argument("--rounds", type=positive_int, default=30, help="timed rounds (each calls every variant once)")
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS), help="variants to time")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_compilation_cache", False)  # first calls are compilations, not cache loads
    report = {"command": "python benchmarks/perf/projection_variants.py " + " ".join(argv or sys.argv[1:]),
              "machine": machine(), "load_before": os.getloadavg(), "rounds": args.rounds, "results": {}}
    for samples in args.samples:
        report["results"][str(samples)] = measure(samples, args.rounds, args.variants)
        report["load_after"] = os.getloadavg()
        write_json(args.json, report)
        row = ", ".join(f"{name} {r['median_ms']:.1f}" for name, r in report["results"][str(samples)].items())
        print(f"{samples} rows, median ms: {row}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
