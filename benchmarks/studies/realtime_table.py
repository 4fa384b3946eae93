"""What planning speed buys in the closed loop: collisions and speed, the simulator waiting for every plan against
real time (plans take effect after their measured compute time), on the dense four-lane road.

    python benchmarks/studies/realtime_table.py --json out/realtime_table.json [--out out/realtime] [--episodes 50]
        [--duration S] [--seed 42] [--workers 1] [--configs bilevel-250 ...] [--latencies sync measured]

Each configuration (``bilevel`` at its default, 250 and 1000 samples, ``vqvae-filter`` at its own sample count) runs
once per latency as a ``driveopt bench`` into a folder of its own under ``--out`` (``NAME-LATENCY``): the same as

    driveopt bench --scenarios four-lane-d3.0 --planners bilevel --samples 250 --latency measured \\
        --episodes 50 --workers 1 --out out/realtime/bilevel-250-measured

so every folder resumes on its own (an interrupted run loses at most the episode in flight) and refuses mixing
settings. After each folder the table is rewritten whole into ``--json``: per configuration and latency, episodes,
collisions, collision rate (95% Wilson interval), mean speed over collision-free episodes and over all, planning
time median and p95 [ms], and for real time the delays of the delivered plans (median and largest, in policy
periods) and the share of plans that took effect later than the next step. ``--workers 1`` (the default) gives
each episode every CPU the run may use: with measured latency, workers that share cores plan slower and so drive
with longer delays. State the machine and its load next to the numbers.
"""

from __future__ import annotations

import argparse
import math
import platform
from pathlib import Path
from typing import Any

import numpy as np

from driveopt.experiments.bench import BenchSpec, run_bench
from driveopt.experiments.runner import usable_cpus
from driveopt.experiments.store import load_records
from driveopt.files import write_json

SCENARIO = "four-lane-d3.0"
CONFIGS: dict[str, tuple[str, int | None]] = {  # name -> (planner, samples; None: the planner's own)
    "bilevel": ("bilevel", None),  # the default planner at its real-time default (driveopt.registry.REALTIME_SAMPLES)
    "bilevel-250": ("bilevel", 250),
    "bilevel-1000": ("bilevel", 1000),
    "vqvae-filter": ("vqvae-filter", None),
}
LATENCIES = ("sync", "measured")


def bench_spec(config: str, latency: str, args: argparse.Namespace) -> BenchSpec:
    """The bench of one configuration at one latency (``sync``, ``measured`` or a number of ms)."""
    planner, samples = CONFIGS[config]
    given = {"samples": samples, "duration": args.duration, "latency": None if latency == "sync" else _latency(latency)}
    options = {key: value for key, value in given.items() if value is not None}
    return BenchSpec((SCENARIO,), (planner,), (args.seed,), args.episodes, options)


def _latency(text: str) -> str | float:
    return text if text == "measured" else float(text)


def delays(records: list[dict[str, Any]]) -> dict[str, Any]:
    """The delays of the plans delivered in real-time episodes [policy periods]: median, largest, share over 1
    (each episode's first plan, waited for, left out); empty for synchronous episodes."""
    periods = np.concatenate([np.asarray(r.get("plan_periods", [])[1:], float) for r in records]) if records else []
    if len(periods) == 0:
        return {}
    return {"plan_periods_median": float(np.median(periods)), "plan_periods_max": int(np.max(periods)),
            "share_later_than_next_step": float(np.mean(periods > 1))}


def row(config: str, latency: str, folder: Path, summary: dict[str, Any]) -> dict[str, Any]:
    """One line of the table from a bench folder and its summary row."""
    records = load_records(folder / "episodes.jsonl")
    clean = {key: (None if isinstance(value, float) and math.isnan(value) else value) for key, value in summary.items()}
    return {"config": config, "latency": latency, "episodes": clean["episodes"],
            "collisions": sum(bool(r["collided"]) for r in records), "collision_rate": clean["collision_rate"],
            "collision_ci": [clean["collision_ci_low"], clean["collision_ci_high"]],
            "mean_speed_collision_free": clean["mean_speed_collision_free"], "mean_speed_all": clean["mean_speed_all"],
            "plan_ms_median": clean["plan_ms_median"], "plan_ms_p95": clean["plan_ms_p95"], **delays(records),
            "folder": str(folder)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, required=True, help="the table, rewritten after every folder")
    parser.add_argument("--out", type=Path, default=Path("out/realtime"), help="parent of the bench folders")
    parser.add_argument("--configs", nargs="+", choices=list(CONFIGS), default=list(CONFIGS))
    parser.add_argument("--latencies", nargs="+", default=list(LATENCIES), help="sync, measured or a number of ms")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--duration", type=float, help="[s] per episode (default: the scenario's)")
    parser.add_argument("--seed", type=int, default=42)
    parser.add_argument("--workers", type=int, default=1, help="parallel episodes (1: each has every CPU)")
    args = parser.parse_args(argv)
    specs = {(config, latency): bench_spec(config, latency, args) for config in args.configs for latency in args.latencies}
    for spec in specs.values():
        spec.check()  # every bad option before the first episode
    table = {"scenario": SCENARIO, "seed": args.seed, "machine": platform.node(), "cpus": len(usable_cpus()),
             "workers": args.workers, "rows": []}
    for (config, latency), spec in specs.items():
        folder = args.out / f"{config}-{latency}"
        summary = run_bench(spec, folder, workers=args.workers)[0]
        table["rows"].append(row(config, latency, folder, summary))
        write_json(args.json, table)
        print(f"{config} / {latency}: {table['rows'][-1]}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
