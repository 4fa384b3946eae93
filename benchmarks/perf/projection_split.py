"""Can one projection use both CPU cores? The batch projection split into parts, timed against the whole batch.

    python benchmarks/perf/projection_split.py --json out/projection-split.json [--samples 250 1000] [--calls 40]

The projection of the default planner (``PlannerConfig``: 20 iterations, early stop off so that every call does the
same work) on the built-in ``dense-snapshot`` problem, for one batch of ``--samples`` set-point-QP trajectories, run
four ways, each in a fresh process (the host device count is fixed when JAX starts):

- ``whole``: the batch in one ``project`` call, one CPU device (how the planner runs it);
- ``one-core``: the same in a process bound to one CPU, so that XLA splits none of its loops over two threads (what
  its own splitting of the larger loops gains; Linux only, skipped where a process cannot be bound);
- ``halves``: two ``project`` calls on the two halves of the batch in one jitted graph (two independent loops, which
  XLA's CPU runtime may run at once);
- ``two-devices``: the batch split over two host CPU devices (``--xla_force_host_platform_device_count=2``) with
  ``jax.shard_map``, one half per device.

Each is timed as the median of ``--calls`` calls after its compilation (JAX's persistent compilation cache off),
with the planner's CPU compiler options; ``max_abs_diff`` is the largest difference of its projected coefficients
from the whole batch's (the halves and devices stop and round on their own, so results are close, not equal). The
machine's load average is recorded with each case. Measurement only: the planner's code is not changed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

from driveopt.cli.common import positive_int
from driveopt.files import write_json

WAYS = ("whole", "one-core", "halves", "two-devices")


def measure(way: str, samples: int, calls: int) -> dict:
    """One case in this process (for ``two-devices``, started with two host devices)."""
    if way == "one-core":  # before JAX starts: XLA sizes its thread pool and splits its loops by the usable CPUs
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    import jax
    import jax.numpy as jnp
    import numpy as np
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    from driveopt.config import PlannerConfig
    from driveopt.planner import setpoint_batch
    from driveopt.problem import build_problem
    from driveopt.projection import project
    from driveopt.qp import make_model
    from driveopt.scene import load_scene
    from driveopt.xla import XLA_CPU_COMPILER_OPTIONS, supported_compiler_options

    config = PlannerConfig().replace(projection={"tolerance": 0.0})
    model = make_model(config.basis, config.qp)
    problem = build_problem(load_scene("dense-snapshot"), config.basis)
    key = jax.random.PRNGKey(0)
    setpoints = jnp.concatenate([16 + 4 * jax.random.normal(key, (samples, 4)),
                                 6 + 4 * jax.random.normal(jax.random.fold_in(key, 1), (samples, 4))], 1)
    coeffs, b_x, b_y = setpoint_batch(model, problem, config, setpoints)
    b_x, b_y = (jnp.broadcast_to(b, (samples, b.shape[-1])) for b in (b_x, b_y))
    options = supported_compiler_options(XLA_CPU_COMPILER_OPTIONS)

    def whole(t, bx, by):
        return project(model, problem, t, bx, by, config.projection).coeffs

    half = samples // 2
    if way in ("whole", "one-core"):
        fn = jax.jit(whole, compiler_options=options)
    elif way == "halves":
        fn = jax.jit(lambda t, bx, by: jnp.concatenate([whole(t[:half], bx[:half], by[:half]),
                                                        whole(t[half:], bx[half:], by[half:])]),
                     compiler_options=options)
    else:
        mesh = Mesh(np.array(jax.devices()[:2]), ("batch",))
        split = PartitionSpec("batch")
        # check_vma off: each device's loop stops on its own samples (its error is not reduced over the devices)
        fn = jax.jit(jax.shard_map(whole, mesh=mesh, in_specs=(split,) * 3, out_specs=split, check_vma=False),
                     compiler_options=options)
        coeffs, b_x, b_y = (jax.device_put(a, NamedSharding(mesh, split)) for a in (coeffs, b_x, b_y))
    load_before = os.getloadavg()[0]
    start = time.perf_counter()
    out = fn(coeffs, b_x, b_y).block_until_ready()
    first = time.perf_counter() - start
    times = []
    for _ in range(calls):
        start = time.perf_counter()
        fn(coeffs, b_x, b_y).block_until_ready()
        times.append(time.perf_counter() - start)
    reference = jax.jit(whole, compiler_options=options)(coeffs, b_x, b_y)
    steady = float(np.median(times))
    return {"way": way, "samples": samples, "calls": calls, "devices": len(jax.devices()),
            "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
            "compile_s": round(first - steady, 3), "median_ms": round(1e3 * steady, 3),
            "p90_ms": round(1e3 * float(np.percentile(times, 90)), 3),
            "max_abs_diff": float(jnp.max(jnp.abs(jnp.asarray(out) - jnp.asarray(reference)))),
            "load_before": round(load_before, 2), "load_after": round(os.getloadavg()[0], 2)}


def run_case(way: str, samples: int, calls: int) -> dict:
    env = {**os.environ, "DRIVEOPT_COMPILATION_CACHE": "0"}
    if way == "two-devices":
        env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2").strip()
    proc = subprocess.run([sys.executable, __file__, "--one", way, "--samples", str(samples), "--calls", str(calls)],
                          capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise SystemExit(f"projection_split: case {way} at {samples} samples failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="projection_split.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", help="results file (written after every case); required")
    parser.add_argument("--samples", type=positive_int, nargs="+", default=[250, 1000], help="batch sizes (even)")
    parser.add_argument("--calls", type=positive_int, default=40, help="timed calls per case")
    parser.add_argument("--one", choices=WAYS, help=argparse.SUPPRESS)  # a child process's single case
    args = parser.parse_args(argv)
    if not args.one and not args.json:
        parser.error("--json is required")
    if any(n % 2 for n in args.samples):
        parser.error("--samples must be even (the batch is split in halves)")
    if args.one:
        print(json.dumps(measure(args.one, args.samples[0], args.calls)))
        return 0
    record = {"machine": platform.machine(), "cpus": os.cpu_count(), "cases": []}
    for samples in args.samples:
        for way in (w for w in WAYS if w != "one-core" or hasattr(os, "sched_setaffinity")):
            case = run_case(way, samples, args.calls)
            record["cases"].append(case)
            print(f"{samples:5d} {way:12s} {case['median_ms']:8.2f} ms (p90 {case['p90_ms']:.2f}), "
                  f"compile {case['compile_s']:.2f} s, max |diff| {case['max_abs_diff']:.2g}, load {case['load_before']}",
                  flush=True)
            write_json(args.json, record)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
