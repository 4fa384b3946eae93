"""Simulation time per policy step: driveopt's FastRoad against upstream's Road, same episodes (:mod:`driveopt.sim.fast_road`).

    python benchmarks/perf/sim_speed.py --json out/sim_speed.json [--scenarios four-lane-d3.0 two-lane-d2.5] [--seeds 3] [--duration 20]

For each scenario and seed, one episode of ``--duration`` simulated seconds with the ego driven by highway-env's
IDM/MOBIL (``idm``: no planning, so the time is the simulator's), once with each road. The two runs must
produce the same vehicle states at every step (the benchmark stops with an error otherwise). Per road: the
median over seeds of the wall time per policy step [ms] (env step, sim_frequency / policy_frequency frames),
and the speed-up. Results are written after every scenario.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from driveopt.experiments.rollout import Rollout
from driveopt.files import write_json
from driveopt.registry import get_planner
from driveopt.sim.fast_road import FastRoad

UPSTREAM_LIKE = FastRoad.like


def episode(scenario: str, seed: int, duration: float, fast: bool) -> tuple[float, list[np.ndarray]]:
    """(wall seconds per policy step, the vehicles' states per step) of one idm episode."""
    FastRoad.like = UPSTREAM_LIKE if fast else classmethod(lambda cls, road: road)
    try:
        rollout = Rollout(scenario, get_planner("idm").driver(), seed=seed, duration=duration)
        states, start = [], time.perf_counter()
        for step in rollout:
            road = step.env.unwrapped.road
            states.append(np.array([[*v.position, v.speed, v.heading, v.crashed] for v in road.vehicles]))
        return (time.perf_counter() - start) / max(len(states), 1), states
    finally:
        FastRoad.like = UPSTREAM_LIKE


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", default="out/sim_speed.json", help="results file (rewritten after every scenario)")
    parser.add_argument("--scenarios", nargs="+", default=["four-lane-d3.0", "two-lane-d2.5"])
    parser.add_argument("--seeds", type=int, default=3, help="episodes per scenario (seeds 0..N-1)")
    parser.add_argument("--duration", type=float, default=20.0, help="[s] simulated time per episode")
    args = parser.parse_args(argv)
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    report = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(), "duration_s": args.duration,
              "driver": "idm", "results": []}
    for scenario in args.scenarios:
        times: dict[str, list[float]] = {"upstream": [], "fast": []}
        for seed in range(args.seeds):
            t_fast, fast = episode(scenario, seed, args.duration, True)
            t_up, upstream = episode(scenario, seed, args.duration, False)
            if len(fast) != len(upstream) or not all(np.array_equal(a, b) for a, b in zip(fast, upstream)):
                print(f"error: {scenario} seed {seed}: FastRoad's episode differs from upstream's", file=sys.stderr)
                return 1
            times["fast"].append(t_fast)
            times["upstream"].append(t_up)
            print(f"{scenario} seed {seed}: {1e3 * t_up:.1f} -> {1e3 * t_fast:.1f} ms per policy step", flush=True)
        upstream_ms, fast_ms = 1e3 * float(np.median(times["upstream"])), 1e3 * float(np.median(times["fast"]))
        report["results"].append({"scenario": scenario, "episodes": args.seeds, "identical": True,
                                  "upstream_ms_per_step": upstream_ms, "fast_ms_per_step": fast_ms,
                                  "speedup": upstream_ms / fast_ms})
        write_json(path, report)  # strict JSON, whole or not at all
    return 0


if __name__ == "__main__":
    sys.exit(main())
