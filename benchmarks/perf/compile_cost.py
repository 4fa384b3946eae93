"""What one planner compilation costs on the CPU, per set of XLA compiler options: seconds and memory mappings.

    python benchmarks/perf/compile_cost.py --json out/compile_cost.json [--calls 10] [--samples 1000] [--cases NAME ...]

Each case runs in a fresh process (nothing compiled yet) on the built-in ``dense-snapshot`` problem with the
default planner configuration (``--samples`` samples): the compile time (first ``plan()`` call minus the
steady-state median; JAX's persistent compilation cache off), the steady-state median of ``--calls`` further calls,
and the process's memory mappings (lines of ``/proc/self/maps``) before the first call, after it, and after
``jax.clear_caches()``. jaxlib 0.10 maps each fused kernel of a CPU executable separately, and a process that reaches Linux's ``vm.max_map_count``
dies at its next compilation: ``compilations_to_the_limit`` is how many such compilations fit. A case's options
are merged over the planner's own (``driveopt.xla.XLA_CPU_COMPILER_OPTIONS``). Every finished case is
written at once; a rerun skips the cases already in the file.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

from driveopt.files import write_json

# name -> XLA compiler options merged over the planner's (all are per-jit options of jaxlib 0.10's CPU compiler)
CASES: dict[str, dict] = {
    "planner-default": {},
    "llvm-cheap-passes": {"xla_llvm_disable_expensive_passes": True},
    "copy-insertion-region-analysis": {"xla_cpu_copy_insertion_use_region_analysis": True},
    "no-fusion-emitters": {"xla_cpu_use_fusion_emitters": False},
    "codegen-in-one-part": {"xla_cpu_parallel_codegen_split_count": 1},
    "backend-o1": {"xla_backend_optimization_level": 1},
    "region-analysis-and-o1": {"xla_cpu_copy_insertion_use_region_analysis": True, "xla_backend_optimization_level": 1},
}


def mappings() -> int | None:
    """Lines of /proc/self/maps (None off Linux)."""
    try:
        with open("/proc/self/maps") as f:
            return sum(1 for _ in f)
    except OSError:
        return None


def map_limit() -> int | None:
    try:
        return int(Path("/proc/sys/vm/max_map_count").read_text())
    except (OSError, ValueError):
        return None


def measure(options: dict, calls: int, samples: int) -> dict:
    """One case, in this process (it must not have compiled the planner yet)."""
    import jax
    import numpy as np

    from driveopt import planner
    from driveopt.config import PlannerConfig
    from driveopt.problem import build_problem
    from driveopt.scene import load_scene
    from driveopt.xla import supported_compiler_options

    merged = {**planner.XLA_CPU_COMPILER_OPTIONS, **options}
    unsupported = sorted(set(merged) - set(supported_compiler_options(merged)))
    if unsupported:
        raise SystemExit(f"compile_cost: this jaxlib's CPU compiler does not accept {', '.join(unsupported)}")
    planner.XLA_CPU_COMPILER_OPTIONS = merged  # read by the planner's first compilation
    config = PlannerConfig().replace(sampler={"num_samples": samples})
    problem = build_problem(load_scene("dense-snapshot"), config.basis)
    planner.compiled_solve()  # the jit wrapper (and its option probes) before counting
    gc.collect()
    before = mappings()
    start = time.perf_counter()
    planner.plan(problem, config, key=jax.random.PRNGKey(0))
    first = time.perf_counter() - start
    compiled = mappings()
    times = []
    for i in range(calls):
        start = time.perf_counter()
        planner.plan(problem, config, key=jax.random.PRNGKey(i + 1))
        times.append(time.perf_counter() - start)
    steady = float(np.median(times))
    jax.clear_caches()
    gc.collect()
    cleared = mappings()
    return {"options": merged, "samples": samples, "calls": calls, "compile_s": round(first - steady, 3),
            "steady_median_ms": round(1e3 * steady, 2), "steady_p90_ms": round(1e3 * float(np.percentile(times, 90)), 2),
            "maps_before": before, "maps_after_compile": compiled, "maps_after_clear_caches": cleared}


def run_case(name: str, calls: int, samples: int) -> dict:
    """``name`` measured in a fresh Python process."""
    proc = subprocess.run([sys.executable, __file__, "--one", name, "--calls", str(calls), "--samples", str(samples)],
                          capture_output=True, text=True,
                          env={**os.environ, "DRIVEOPT_COMPILATION_CACHE": "0"})  # compilations, not cache loads
    if proc.returncode != 0:
        raise SystemExit(f"compile_cost: case {name} failed:\n{proc.stderr[-3000:]}")
    record = json.loads(proc.stdout.strip().splitlines()[-1])
    limit, before = map_limit(), record["maps_before"]
    per_compile = None if before is None else record["maps_after_compile"] - before
    record["maps_per_compilation"] = per_compile
    record["compilations_to_the_limit"] = limit // per_compile if limit and per_compile else None
    return {"case": name, **record}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="compile_cost.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", help="results file (appended to case by case; a rerun skips its cases)")
    parser.add_argument("--calls", type=int, default=10, help="steady-state calls per case")
    parser.add_argument("--samples", type=int, default=1000, help="samples per plan")
    parser.add_argument("--cases", nargs="+", choices=sorted(CASES), help="cases to run (default: all)")
    parser.add_argument("--one", choices=sorted(CASES), help=argparse.SUPPRESS)  # a child process's single case
    args = parser.parse_args(argv)
    if args.calls < 1 or args.samples < 1:
        parser.error("--calls and --samples must be at least 1")
    if args.one:
        print(json.dumps(measure(CASES[args.one], args.calls, args.samples)))
        return 0
    if not args.json:
        parser.error("--json is required")
    from tqdm import tqdm

    path = Path(args.json)
    doc = json.loads(path.read_text()) if path.exists() else {}
    if doc and (doc.get("calls"), doc.get("samples")) != (args.calls, args.samples):
        raise SystemExit(f"compile_cost: {path} holds a run with other --calls/--samples; use another file")
    doc = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(), "vm_max_map_count": map_limit(),
           "calls": args.calls, "samples": args.samples, "cases": doc.get("cases", [])}
    done = {c["case"] for c in doc["cases"]}
    todo = [name for name in (args.cases or CASES) if name not in done]
    path.parent.mkdir(parents=True, exist_ok=True)
    for name in tqdm(todo, desc="compile_cost", unit="case"):
        doc["cases"].append(run_case(name, args.calls, args.samples))
        write_json(path, doc)  # strict JSON, whole or not at all
    for c in doc["cases"]:
        print(f"{c['case']:32s} compile {c['compile_s']:6.1f} s  steady {c['steady_median_ms']:8.1f} ms  "
              f"{c['maps_per_compilation']} maps/compilation")
    return 0


if __name__ == "__main__":
    sys.exit(main())
