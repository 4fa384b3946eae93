"""Where a planning call's time goes, kernel by kernel: the compiled planner's own kernels, timed by JAX's profiler.

    python benchmarks/perf/kernel_profile.py --json out/kernel-profile.json [--planner bilevel] [--samples 250]
        [--problem dense-snapshot] [--calls 5] [--fixed-work] [--top 25]

``benchmarks/perf/call_profile.py`` times the parts of a call jitted one by one; this looks inside the one executable that
``plan()`` runs. The planner (``--planner``, the registry's configuration at ``--samples`` samples; ``--fixed-work``:
the projection's early stop off, as in ``benchmarks/perf/latency.py``) is compiled with XLA's per-kernel trace annotations
(the CPU compiler option ``xla_cpu_enable_xprof_traceme``; JAX's persistent compilation cache off), warmed up, and
``--calls`` calls are traced with ``jax.profiler.trace``. Every kernel the trace shows (one per fusion, product or
library call of the optimised HLO, named as there) is recorded with its time per planning call [us] and how many times
a call runs it: a projection iteration's kernels run (sampler iterations x projection iterations) times, a sampler
iteration's once per iteration. ``groups`` sums the kernels by that count, which splits a call into its loops.

The profiler adds its own overhead (the kernel times sum to more than an untraced call's median, ``call_ms``, which
is recorded too); read the shares and the differences between kernels, not the absolute sum. The machine's load
average is recorded before and after. Measurement only: the planner's code is not changed.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

import jax
import numpy as np

from driveopt import planner
from driveopt.cli.common import positive_int
from driveopt.files import write_json
from driveopt.problem import build_problem
from driveopt.registry import get_optimiser
from driveopt.scene import load_scene

if __package__ in (None, ""):  # run as a file: the repository root on the path, for the package import below
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks.perf.call_profile import machine  # noqa: E402

TRACE_OPTION = {"xla_cpu_enable_xprof_traceme": True}
# Trace events that are not kernels: Python frames ("$file:line name"), the runtime's own scopes ("Class::method"),
# the jit dispatch ("PjitFunction(name)"), host copies, and the end markers of asynchronous kernels.
_NOT_KERNELS = ("$", "PjitFunction(", "np.", "end: ")


def is_kernel(name: str) -> bool:
    return not name.startswith(_NOT_KERNELS) and "::" not in name


def kernel_times(events: list[dict], calls: int) -> list[dict]:
    """Per kernel of a trace's complete events ("ph" "X", durations in us): time per call [us] and runs per call,
    the costliest first."""
    total, runs = Counter(), Counter()
    for event in events:
        if event.get("ph") == "X" and is_kernel(event.get("name", "")):
            total[event["name"]] += event["dur"]
            runs[event["name"]] += 1
    return [{"kernel": name, "us_per_call": t / calls, "runs_per_call": runs[name] / calls}
            for name, t in total.most_common()]


def groups(kernels: list[dict]) -> list[dict]:
    """The kernels summed by how many times a call runs them, the costliest group first."""
    by_runs = defaultdict(lambda: {"kernels": 0, "ms_per_call": 0.0})
    for k in kernels:
        group = by_runs[k["runs_per_call"]]
        group["kernels"] += 1
        group["ms_per_call"] += k["us_per_call"] / 1e3
    return sorted(({"runs_per_call": runs, **g} for runs, g in by_runs.items()), key=lambda g: -g["ms_per_call"])


def read_trace(folder: Path) -> list[dict]:
    """The complete events of the Perfetto trace that ``jax.profiler.trace(folder, create_perfetto_trace=True)`` wrote."""
    found = sorted(folder.rglob("perfetto_trace.json.gz"))
    if not found:
        raise SystemExit(f"kernel_profile: the profiler wrote no perfetto_trace.json.gz under {folder}")
    with gzip.open(found[-1], "rt") as f:
        trace = json.load(f)
    return trace["traceEvents"] if isinstance(trace, dict) else trace


def profile(planner_name: str, samples: int, problem_name: str, calls: int, fixed_work: bool) -> dict:
    spec = get_optimiser(planner_name).with_samples(samples)
    if fixed_work:
        spec = spec.with_overrides(projection={"tolerance": 0.0})
    config = spec.config
    scene = load_scene(problem_name)
    prior, safety_filter = spec.prior(scene.road.num_lanes), spec.safety_filter(scene.road.num_lanes)
    problem = build_problem(scene, config.basis, braking_time=spec.braking_time, selection_time=spec.selection_time)

    def call(seed: int):
        return planner.plan(problem, config, key=jax.random.PRNGKey(seed), prior=prior, safety_filter=safety_filter,
                            x_offset=scene.ego.x, method=spec.method)

    start = time.perf_counter()
    first = call(0)
    compile_s = time.perf_counter() - start
    untraced = []
    for seed in range(1, 4):
        start = time.perf_counter()
        call(seed)
        untraced.append(time.perf_counter() - start)
    with tempfile.TemporaryDirectory() as folder:
        with jax.profiler.trace(folder, create_perfetto_trace=True):
            for seed in range(calls):
                call(100 + seed)
        kernels = kernel_times(read_trace(Path(folder)), calls)
    if not kernels:
        raise SystemExit("kernel_profile: the trace holds no kernels (was the planner compiled before the annotations "
                         "were asked for?)")
    return {"planner": planner_name, "samples": samples, "problem": problem_name, "fixed_work": fixed_work,
            "calls": calls, "status": first.status.name, "first_call_s": compile_s,
            "call_ms": 1e3 * float(np.median(untraced)), "kernel_sum_ms": sum(k["us_per_call"] for k in kernels) / 1e3,
            "groups": groups(kernels), "kernels": kernels}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", required=True, help="results file")
    parser.add_argument("--planner", default="bilevel", help="registry planner (default bilevel)")
    parser.add_argument("--samples", type=positive_int, default=250, help="samples per sampler iteration")
    parser.add_argument("--problem", default="dense-snapshot", help="built-in problem or JSON file")
    parser.add_argument("--calls", type=positive_int, default=5, help="traced calls after the warm-up")
    parser.add_argument("--fixed-work", action="store_true", help="projection early stop off (every call the same work)")
    parser.add_argument("--top", type=int, default=25, help="kernels printed")
    args = parser.parse_args(argv)
    if jax.default_backend() != "cpu":
        raise SystemExit("kernel_profile: the per-kernel annotations are a CPU compiler option; this backend is "
                         f"{jax.default_backend()}")
    jax.config.update("jax_enable_compilation_cache", False)  # a compilation with the annotations, not a cache load
    planner.XLA_CPU_COMPILER_OPTIONS = {**planner.XLA_CPU_COMPILER_OPTIONS, **TRACE_OPTION}
    planner.exported_solve.cache_clear()  # the planner's jit reads its options when first built
    load_before = os.getloadavg()
    result = profile(args.planner, args.samples, args.problem, args.calls, args.fixed_work)
    report = {"machine": machine(), "load_before": load_before, "load_after": os.getloadavg(), **result}
    path = write_json(args.json, report)  # strict JSON, whole or not at all
    print(f"{args.planner} at {args.samples} samples: untraced call {result['call_ms']:.1f} ms, kernels "
          f"{result['kernel_sum_ms']:.1f} ms per traced call")
    for g in result["groups"][:6]:
        print(f"  run {g['runs_per_call']:g} x per call: {g['kernels']} kernels, {g['ms_per_call']:.2f} ms")
    for k in result["kernels"][:args.top]:
        print(f"  {k['us_per_call'] / max(k['runs_per_call'], 1e-9):9.1f} us x {k['runs_per_call']:g}  {k['kernel']}")
    print(f"wrote {path} (load average {load_before[0]:.2f} before, {report['load_after'][0]:.2f} after)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
