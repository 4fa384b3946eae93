"""Closed-loop episodes per hour: ``driveopt bench --lockstep E`` for several E against ``--workers W`` one by one.

    python benchmarks/perf/lockstep_throughput.py --json out/lockstep_throughput.json [--lockstep 1 2 4 8] [--workers 2]
        [--lockstep-workers 1] [--episodes 16] [--duration 5] [--samples 250] [--scenario four-lane-d3.0]
        [--planner bilevel]

Each setting runs as its own ``driveopt bench`` process (as a campaign would), into a fresh folder: first a warm-up
run (one episode per slot and worker, 0.3 s each) that fills the compilation cache, then the timed run of
``--episodes`` episodes of ``--duration`` simulated seconds. Per setting: the timed run's wall time, episodes per hour
(3600 x episodes / wall time, start-up and the cached compilation included), the mean and median planning-call time
from the records (a lock-step call plans for all its episodes) and the collisions, with the load average before and
after. The file is rewritten after every setting (strict JSON), and a rerun with the same parameters keeps the settings
it holds and runs the others (resume). On a busy machine the figures are noisy: the load average is recorded so that
a reader can tell. ``--lockstep-workers W`` runs each lock-step setting in W worker processes (each arm cut into about W cells).

Agreement: each setting keeps its episodes' outcomes (collided, steps, statuses, mean speed); every lock-step setting
is compared with the first one-by-one setting on the same episodes (``agreement``: episodes compared, how many have
the same collision, steps and status counts, and the largest mean-speed difference [m/s]).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from driveopt.experiments.store import load_records
from driveopt.files import write_json

WARM_UP_DURATION = 0.3  # [s] simulated time of each warm-up episode (it compiles, or loads the compiled call)


def bench_argv(out: Path, args: argparse.Namespace, episodes: int, duration: float, setting: dict) -> list[str]:
    """The ``driveopt bench`` command line of one run of ``setting``: ``{"workers": W}``, ``{"lockstep": E}`` or
    both."""
    argv = [sys.executable, "-m", "driveopt.cli", "bench", "--scenarios", args.scenario, "--planners", args.planner,
            "--seeds", str(args.seed), "--episodes", str(episodes), "--duration", str(duration),
            "--samples", str(args.samples), "--out", str(out)]
    if "lockstep" in setting:
        argv += ["--lockstep", str(setting["lockstep"])]
    if "workers" in setting:
        argv += ["--workers", str(setting["workers"])]
    return argv


def run_setting(args: argparse.Namespace, setting: dict, folder: Path) -> dict:
    """Warm up, then time one run of ``setting``; its figures."""
    width = setting.get("lockstep", 1) * setting.get("workers", 1)
    subprocess.run(bench_argv(folder / "warm-up", args, width, WARM_UP_DURATION, setting), check=True,
                   stdout=subprocess.DEVNULL)
    load_before = list(os.getloadavg())
    start = time.perf_counter()
    subprocess.run(bench_argv(folder / "timed", args, args.episodes, args.duration, setting), check=True,
                   stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    records = load_records(folder / "timed" / "episodes.jsonl")
    plan_ms = np.asarray([ms for r in records for ms in r["plan_ms"]] or [np.nan])
    outcomes = {f"{r['seed']}/{r['episode']}": {"collided": bool(r["collided"]), "steps": int(r["steps"]),
                                                "statuses": r["statuses"], "mean_speed": float(r["mean_speed"])}
                for r in records}
    return {**setting, "episodes": len(records), "wall_s": wall, "episodes_per_hour": 3600.0 * len(records) / wall,
            "steps": int(sum(r["steps"] for r in records)), "plan_ms_mean": float(np.mean(plan_ms)),
            "plan_ms_median": float(np.median(plan_ms)), "collisions": int(sum(r["collided"] for r in records)),
            "load_before": load_before, "load_after": list(os.getloadavg()), "outcomes": outcomes}


def agreement(run: dict, reference: dict) -> dict:
    """How ``run``'s episodes agree with ``reference``'s on the episodes both ran."""
    shared = sorted(set(run["outcomes"]) & set(reference["outcomes"]))
    pairs = [(run["outcomes"][k], reference["outcomes"][k]) for k in shared]
    same = {field: sum(a[field] == b[field] for a, b in pairs) for field in ("collided", "steps", "statuses")}
    gaps = [abs(a["mean_speed"] - b["mean_speed"]) for a, b in pairs]
    return {"episodes": len(pairs), **{f"same_{field}": n for field, n in same.items()},
            "max_mean_speed_difference": max(gaps) if gaps else None}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", default="out/lockstep_throughput.json", help="results file (rewritten after every setting)")
    parser.add_argument("--lockstep", type=int, nargs="+", default=[1, 2, 4, 8], help="slot counts E to time")
    parser.add_argument("--workers", type=int, nargs="*", default=[2], help="one-by-one worker counts to time against")
    parser.add_argument("--lockstep-workers", type=int, default=1, help="worker processes of each lock-step setting")
    parser.add_argument("--episodes", type=int, default=16, help="episodes of each timed run")
    parser.add_argument("--duration", type=float, default=5.0, help="[s] simulated time per episode")
    parser.add_argument("--samples", type=int, default=250, help="samples per sampler iteration")
    parser.add_argument("--scenario", default="four-lane-d3.0")
    parser.add_argument("--planner", default="bilevel")
    parser.add_argument("--seed", type=int, default=42)
    args = parser.parse_args(argv)
    counts = args.lockstep + args.workers + [args.lockstep_workers, args.episodes, args.samples]
    if min(counts) < 1 or not args.duration > 0:
        parser.error("slot and worker counts, episodes and samples must be >= 1 and the duration > 0")
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    parameters = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
                  "scenario": args.scenario, "planner": args.planner, "samples": args.samples,
                  "duration_s": args.duration, "episodes": args.episodes, "seed": args.seed}
    report = {**parameters, "results": []}
    if path.exists():
        held = json.loads(path.read_text())
        if {k: held.get(k) for k in parameters} != parameters:
            parser.error(f"{path} holds a run with other parameters; give another --json")
        report = held
    together = {} if args.lockstep_workers == 1 else {"workers": args.lockstep_workers}
    settings = [{"workers": w} for w in args.workers] + [{"lockstep": e, **together} for e in args.lockstep]
    for setting in settings:
        if any({k: r.get(k) for k in ("lockstep", "workers")} == {k: setting.get(k) for k in ("lockstep", "workers")}
               for r in report["results"]):
            continue  # measured by an earlier run of this file
        with tempfile.TemporaryDirectory(prefix="lockstep-throughput-") as folder:
            result = run_setting(args, setting, Path(folder))
        report["results"].append(result)
        reference = next((r for r in report["results"] if "lockstep" not in r), None)
        for r in report["results"]:
            if "lockstep" in r and reference is not None:
                r["agreement"] = agreement(r, reference)
        write_json(path, report)  # strict JSON, whole or not at all
        print(f"{setting}: {result['episodes_per_hour']:.0f} episodes/h ({result['wall_s']:.1f} s, plan "
              f"{result['plan_ms_median']:.0f} ms median)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
