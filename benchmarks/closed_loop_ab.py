"""Does a change keep closed-loop episodes bit for bit? The same episodes under another source tree and this one.

    python benchmarks/closed_loop_ab.py --baseline-src OLD/src --json out/ab.json [--runs PLANNER:SCENARIO ...]
        [--seed 5] [--duration 8]

A refactor that claims to leave planning unchanged keeps every record measured before it valid only if the episodes
are identical, not just statistically alike: one differing float diverges an episode within seconds. Each side runs
in its own process with its tree's ``src`` first on ``PYTHONPATH`` (``--baseline-src``: e.g. the ``src`` of a
``git worktree`` at the old commit; the other side is this checkout's), every run one episode of ``driveopt``'s
closed loop (``run_episode``). The JSON holds, per run, whether speeds, lateral positions and statuses are identical,
the first step where they differ, and each side's ``compile_seconds`` (the driver's warm-up before the timed steps).
Each side's file is written after every run and a rerun skips what it holds; exit status 1 when any run differs.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

# planner:scenario; every learned planner on P2's dense traffic, the others on a road of their own (closed-loop
# warm start and previous plan: bilevel, cvae-mix; the grid baseline: one sampler iteration)
RUNS = ("bilevel:four-lane-d3.0", "cvae-mix:four-lane-d3.0", "vqvae-cem:p2-four-lane-d3.0", "vqvae:p2-four-lane-d3.0",
        "cvae-filter:p2-four-lane-d3.0", "vqvae-filter:p2-four-lane-d3.0", "grid:two-lane-d2.0")


def run_side(runs: list[str], seed: int, duration: float, path: Path) -> None:
    """Run each ``planner:scenario`` episode not yet in ``path`` in this process (this side's code) and add it there."""
    try:
        from driveopt.experiments.rollout import run_episode
    except ModuleNotFoundError:  # a tree from before the episode loop moved to experiments/
        from driveopt.sim.rollout import run_episode
    from driveopt.registry import get_planner

    done = json.loads(path.read_text()) if path.exists() else {}
    for run in runs:
        if run in done:
            continue
        planner, scenario = run.split(":")
        episode = run_episode(scenario, get_planner(planner), seed=seed, duration=duration)
        done[run] = {"speeds": [float(v) for v in episode.speeds], "lateral": [float(v) for v in episode.lateral],
                     "statuses": dict(episode.statuses), "compile_seconds": episode.compile_seconds}
        path.write_text(json.dumps(done))
        print(f"  {run}: {len(episode.speeds)} steps, compile {episode.compile_seconds:.1f} s", flush=True)


def first_difference(a: dict, b: dict) -> int | None:
    """The first step at which two episodes' speeds or lateral positions differ (None: identical, same length)."""
    for step, pair in enumerate(zip(zip(a["speeds"], a["lateral"]), zip(b["speeds"], b["lateral"]))):
        if pair[0] != pair[1]:
            return step
    return None if len(a["speeds"]) == len(b["speeds"]) else min(len(a["speeds"]), len(b["speeds"]))


def compare(baseline: dict, current: dict) -> dict:
    rows = {}
    for run in baseline:
        step = first_difference(baseline[run], current[run])
        identical = step is None and baseline[run]["statuses"] == current[run]["statuses"]
        rows[run] = {"identical": identical, "first_difference_step": step, "steps": len(current[run]["speeds"]),
                     "compile_seconds": {"baseline": baseline[run]["compile_seconds"], "current": current[run]["compile_seconds"]}}
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline-src", type=Path, required=True, help="the other tree's src folder")
    parser.add_argument("--json", type=Path, required=True)
    parser.add_argument("--runs", nargs="+", default=list(RUNS), help="planner:scenario pairs")
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--duration", type=float, default=8.0, help="[s] of each episode")
    parser.add_argument("--side", choices=["baseline", "current"], help=argparse.SUPPRESS)  # a side's child process
    args = parser.parse_args(argv)
    if not (args.baseline_src / "driveopt" / "__init__.py").is_file():
        parser.error(f"--baseline-src {args.baseline_src}: no driveopt package there (give the tree's src folder)")
    if args.duration <= 0:
        parser.error("--duration must be positive")
    bad = [run for run in args.runs if run.count(":") != 1]
    if bad:
        parser.error(f"--runs take planner:scenario, got {' '.join(bad)}")
    sides = {side: args.json.with_name(f"{args.json.stem}.{side}.json") for side in ("baseline", "current")}
    if args.side:
        run_side(args.runs, args.seed, args.duration, sides[args.side])
        return 0
    args.json.parent.mkdir(parents=True, exist_ok=True)
    this_src = Path(__file__).resolve().parents[1] / "src"
    for side, src in (("baseline", args.baseline_src.resolve()), ("current", this_src)):
        print(f"{side}: {src}", flush=True)
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(src), os.environ.get("PYTHONPATH")]))}
        child = [sys.executable, __file__, *(argv if argv is not None else sys.argv[1:]), "--side", side]
        subprocess.run(child, env=env, check=True)
    results = {side: json.loads(path.read_text()) for side, path in sides.items()}
    rows = compare({run: results["baseline"][run] for run in args.runs}, {run: results["current"][run] for run in args.runs})
    args.json.write_text(json.dumps({"seed": args.seed, "duration": args.duration, "baseline_src": str(args.baseline_src),
                                     "runs": rows}, indent=1))
    for run, row in rows.items():
        seconds = row["compile_seconds"]
        verdict = "identical" if row["identical"] else f"DIFFERENT from step {row['first_difference_step']}"
        print(f"{run:32s} {verdict:28s} {row['steps']} steps; compile {seconds['baseline']:.1f} -> {seconds['current']:.1f} s")
    return 0 if all(row["identical"] for row in rows.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
