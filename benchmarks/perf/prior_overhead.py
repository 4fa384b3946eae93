"""Planning-time overhead of the learned CVAE start over the Gaussian start (issue 4).

    python benchmarks/perf/prior_overhead.py --json out/prior_overhead.json [--weights FILE] [--calls 30]

For 250 and 1000 samples (5 sampler iterations x 20 projection iterations, fixed work per call) on
the built-in problem ``dense-snapshot``: compile time and steady-state median / p90 of a full
``plan()`` call with the Gaussian prior and with the CVAE prior, and the median of the prior's
``propose`` alone. Results are written after every case; ``--resume`` keeps finished cases.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

from driveopt.config import PlannerConfig
from driveopt.files import write_json
from driveopt.planner import plan
from driveopt.priors.cvae import load_prior, shipped_weights
from driveopt.problem import build_problem
from driveopt.sampler import GaussianPrior
from driveopt.scene import load_scene


def timed(fn, calls: int) -> tuple[float, list[float]]:
    start = time.perf_counter()
    jax.block_until_ready(fn(0))
    first = time.perf_counter() - start
    times = []
    for i in range(calls):
        start = time.perf_counter()
        jax.block_until_ready(fn(i + 1))
        times.append(time.perf_counter() - start)
    return first, times


def run_case(prior_name: str, prior, samples: int, calls: int) -> dict:
    config = PlannerConfig().replace(
        sampler={"num_samples": samples, "num_constraint_elites": min(100, samples), "num_elites": 40},
        projection={"tolerance": 0.0},
    )
    problem = build_problem(load_scene("dense-snapshot"), config.basis)
    first, times = timed(lambda i: plan(problem, config, key=jax.random.PRNGKey(i), prior=prior).coeffs, calls)
    propose = jax.jit(lambda key: prior.propose(problem, key, samples, None).samples)
    _, propose_times = timed(lambda i: propose(jax.random.PRNGKey(i)), calls)
    median = float(np.median(times))
    return {"case": f"{prior_name}-{samples}", "prior": prior_name, "samples": samples, "calls": calls,
            "compile_s": max(first - median, 0.0), "median_ms": 1e3 * median, "p90_ms": 1e3 * float(np.percentile(times, 90)),
            "propose_median_ms": 1e3 * float(np.median(propose_times))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", default="out/prior_overhead.json")
    parser.add_argument("--weights", help="CVAE checkpoint (default: the shipped four-lane weights)")
    parser.add_argument("--calls", type=int, default=30)
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args(argv)
    weights = args.weights or shipped_weights(4)
    if weights is None:
        print("prior_overhead: error: no CVAE weights shipped; pass --weights", file=sys.stderr)
        return 2
    priors = {"gaussian": GaussianPrior.from_config(PlannerConfig().sampler, PlannerConfig().projection.v_max), "cvae": load_prior(weights)}
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    report = {"weights": str(weights), "results": []}
    if args.resume and path.exists():
        report["results"] = json.loads(path.read_text())["results"]
    done = {r["case"] for r in report["results"]}
    for samples in (250, 1000):
        for name, prior in priors.items():
            if f"{name}-{samples}" in done:
                continue
            result = run_case(name, prior, samples, args.calls)
            report["results"].append(result)
            write_json(path, report)  # strict JSON, whole or not at all
            print(f"{result['case']:>14}: compile {result['compile_s']:.2f} s, plan median {result['median_ms']:.1f} ms "
                  f"(p90 {result['p90_ms']:.1f}), propose {result['propose_median_ms']:.2f} ms")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
