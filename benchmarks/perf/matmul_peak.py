"""This machine's sustained float32 matrix-product throughput under XLA: a bound for what a network can cost.

    python benchmarks/perf/matmul_peak.py --json out/matmul-peak.json [--calls 20]

One jitted call chains 50 products (1000 x 256) @ (256 x 256) (each consumes the last, so none is hoisted or
skipped); the median of ``--calls`` calls after compilation gives GFLOP/s (2 x 1000 x 256 x 256 x 50 per call), with
the machine's load average before and after. PixelCNN sampling of 1000 samples at P2's sizes is 3.9 GFLOP
(docs/results/learned-prior.md): it cannot take less than 3.9 GFLOP over this rate.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

from driveopt.cli.common import positive_int
from driveopt.experiments.runner import cpu_model
from driveopt.files import write_json

ROWS, WIDTH, CHAIN = 1000, 256, 50


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="matmul_peak.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", required=True, help="results file")
    parser.add_argument("--calls", type=positive_int, default=20, help="timed calls")
    args = parser.parse_args(argv)
    import jax
    import numpy as np

    x = jax.random.normal(jax.random.PRNGKey(0), (ROWS, WIDTH))
    w = jax.random.normal(jax.random.PRNGKey(1), (WIDTH, WIDTH)) / np.sqrt(WIDTH)  # keeps the chain's scale
    chain = jax.jit(lambda x, w: jax.lax.fori_loop(0, CHAIN, lambda i, y: y @ w, x))
    load_before = os.getloadavg()[0]
    chain(x, w).block_until_ready()
    times = []
    for _ in range(args.calls):
        start = time.perf_counter()
        chain(x, w).block_until_ready()
        times.append(time.perf_counter() - start)
    median = float(np.median(times))
    flops = 2 * ROWS * WIDTH * WIDTH * CHAIN
    record = {"machine": platform.machine(), "processor": cpu_model(), "cpus": os.cpu_count(), "backend": jax.default_backend(),
              "product": f"({ROWS} x {WIDTH}) @ ({WIDTH} x {WIDTH}) x {CHAIN}", "calls": args.calls,
              "median_ms": round(1e3 * median, 3), "gflop_per_s": round(flops / median / 1e9, 1),
              "load_before": round(load_before, 2), "load_after": round(os.getloadavg()[0], 2)}
    write_json(args.json, record)
    print(f"{record['product']}: median {record['median_ms']} ms, {record['gflop_per_s']} GFLOP/s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
