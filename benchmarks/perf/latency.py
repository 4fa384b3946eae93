"""Planning latency benchmark.

    python benchmarks/perf/latency.py --json out/latency.json [--calls 30] [--resume] [--config overrides.json]
                                 [--batches 250 ...] [--obstacles 10 4 1] [--schedules 5x20 1x100]

For each batch size in {250, 500, 1000} and (sampler iterations x projection
iterations) in {(5, 20), (1, 100)} (``--schedules``), on the built-in 10-neighbour problem
``dense-snapshot`` with 100 nodes: compile time (first call minus the
steady-state median) and the steady-state median / p90 wall time of a full
``plan()`` call over ``--calls`` calls with fresh PRNG keys, plus samples per
second (JAX's persistent compilation cache is off: compile times are compilations). ``--obstacles`` plans against
only the N most relevant of the snapshot's neighbours (``build_problem``'s ``max_obstacles``; default 10, all of
them): what the obstacle terms cost. Results are appended to
the JSON file after every case, so an interrupted run resumes (``--resume``) without repeating finished cases.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import jax
import numpy as np
from tqdm import tqdm

from driveopt.cli.common import config_overrides
from driveopt.config import PlannerConfig
from driveopt.errors import DriveoptError
from driveopt.files import write_json
from driveopt.planner import plan
from driveopt.problem import build_problem
from driveopt.scene import load_scene
from driveopt.xla import XLA_CPU_COMPILER_OPTIONS, supported_compiler_options

BATCHES = (250, 500, 1000)
SCHEDULES = ((5, 20), (1, 100))


MAX_OBSTACLES = 10


def case_name(batch: int, iterations: int, projection: int, obstacles: int = MAX_OBSTACLES) -> str:
    return f"{batch}x{iterations}x{projection}" + (f"-{obstacles}obstacles" if obstacles != MAX_OBSTACLES else "")


def run_case(batch: int, iterations: int, projection: int, calls: int, overrides: dict | None = None,
             obstacles: int = MAX_OBSTACLES) -> dict:
    config = PlannerConfig().replace(**(overrides or {})).replace(
        sampler={"num_samples": batch, "num_iterations": iterations, "num_constraint_elites": min(100, batch), "num_elites": 40},
        projection={"max_iterations": projection, "tolerance": 0.0},  # fixed work per call
    )
    scene = load_scene("dense-snapshot")
    problem = build_problem(scene, config.basis, max_obstacles=obstacles)
    start = time.perf_counter()
    plan(problem, config, key=jax.random.PRNGKey(0))
    first = time.perf_counter() - start
    times, statuses, residuals = [], {}, []
    for i in range(calls):
        start = time.perf_counter()
        result = plan(problem, config, key=jax.random.PRNGKey(i + 1))
        times.append(time.perf_counter() - start)
        statuses[result.status.name] = statuses.get(result.status.name, 0) + 1
        residuals.append(result.residuals["total"])
    median = float(np.median(times))
    return {
        "case": case_name(batch, iterations, projection, obstacles),
        "samples": batch,
        "sampler_iterations": iterations,
        "projection_iterations": projection,
        "neighbours": len(scene.neighbours),
        "obstacles": obstacles,  # planned against (the most relevant neighbours)
        "nodes": config.basis.num_nodes,
        "calls": calls,
        "compile_s": max(first - median, 0.0),
        "median_ms": 1e3 * median,
        "p90_ms": 1e3 * float(np.percentile(times, 90)),
        "samples_per_s": batch * iterations / median,
        "statuses": statuses,  # what the timed calls returned: the answers behind the times
        "median_residual": float(np.median(residuals)),
        "load_average": os.getloadavg(),  # 1, 5, 15 min, at the end of the case
    }


def _schedule(text: str) -> tuple[int, int]:
    """IxP: I sampler iterations of P projection iterations each, both positive."""
    sampler, sep, projection = text.partition("x")
    if not (sep and sampler.isdigit() and projection.isdigit() and int(sampler) > 0 and int(projection) > 0):
        raise argparse.ArgumentTypeError(f"expected IxP with positive integers, e.g. 5x20, got {text!r}")
    return int(sampler), int(projection)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", default="out/latency.json", help="results file (updated after every case)")
    parser.add_argument("--calls", type=int, default=30, help="steady-state calls per case (>= 30 for the README)")
    parser.add_argument("--resume", action="store_true", help="keep finished cases of an existing results file")
    parser.add_argument("--batches", type=int, nargs="+", default=list(BATCHES))
    parser.add_argument("--obstacles", type=int, nargs="+", default=[MAX_OBSTACLES],
                        help="plan against the N most relevant neighbours (1-10; default 10: all of dense-snapshot's)")
    parser.add_argument("--schedules", type=_schedule, nargs="+", default=list(SCHEDULES), metavar="IxP",
                        help="sampler iterations x projection iterations per call (default: 5x20 1x100)")
    parser.add_argument("--config", help="planner-config overrides (JSON, as for driveopt plan --config), applied before "
                                         "each case's samples and iterations")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_compilation_cache", False)  # compile times are compilations, not cache loads
    if args.calls < 1:
        parser.error("--calls must be >= 1")
    if any(not 1 <= n <= MAX_OBSTACLES for n in args.obstacles):
        parser.error(f"--obstacles must be in [1, {MAX_OBSTACLES}]")
    try:
        overrides = config_overrides(args.config)
        PlannerConfig().replace(**overrides)  # e.g. a safety_filter section: not a planner setting
    except DriveoptError as exc:
        print(f"latency: error: {exc}", file=sys.stderr)
        return 2

    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None  # CPUs this process may use
    machine = {"platform": platform.platform(), "cpus": os.cpu_count(), "affinity": affinity, "jax": jax.__version__,
               "device": str(jax.devices()[0])}
    machine["compiler_options"] = supported_compiler_options(XLA_CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else {}
    report = {"machine": machine, "config": overrides, "results": []}
    if args.resume and path.exists():
        try:
            previous = json.loads(path.read_text())
            report["results"] = previous["results"]
        except (json.JSONDecodeError, KeyError, TypeError) as exc:
            print(f"latency: error: cannot resume from {path}: {exc}", file=sys.stderr)
            return 2
        if previous.get("config", {}) != overrides:  # files from before --config hold none
            print(f"latency: error: {path} was measured with config {previous.get('config', {})}, not {overrides}: "
                  "resume with the same --config or write another file", file=sys.stderr)
            return 2
    done = {r["case"] for r in report["results"]}
    cases = [(b, i, p, n) for b in args.batches for i, p in args.schedules for n in args.obstacles
             if case_name(b, i, p, n) not in done]
    for batch, iterations, projection, obstacles in tqdm(cases, desc="latency", unit="case"):
        result = run_case(batch, iterations, projection, args.calls, overrides, obstacles)
        report["results"].append(result)
        write_json(path, report)  # strict JSON, whole or not at all
        tqdm.write(
            f"{result['case']:>12}: compile {result['compile_s']:.2f} s, median {result['median_ms']:.1f} ms, "
            f"p90 {result['p90_ms']:.1f} ms, {result['samples_per_s']:.0f} samples/s"
        )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
