"""``driveopt closed-loop-ab``: does a change keep closed-loop episodes bit for bit?

Runs the same episodes (``--runs``, each ``planner:scenario``, ``--seed``, ``--duration``) under the tree of
``--baseline-src`` (the ``src`` folder of another checkout, e.g. a ``git worktree`` at the old commit) and under this
driveopt, each side in its own process (:mod:`driveopt.experiments.closed_loop_ab`), and writes to ``--json`` whether
each run's speeds, lateral positions and statuses are identical, the first step where they differ and both sides'
compile times; ``--current-config`` overrides this tree's side alone (a default changed since, named as it was).
Each side's episodes are kept beside ``--json`` as they finish: rerun the same command to resume.
Exit status 1 when any run differs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from driveopt.cli.common import UsageError, config_overrides, seed, writable_file
from driveopt.cli.parser import duration


def register(sub) -> None:
    from driveopt.experiments.closed_loop_ab import RUNS  # the module imports only the standard library

    p = sub.add_parser("closed-loop-ab", help="the same closed-loop episodes under another source tree and this one: identical?")
    p.add_argument("--baseline-src", required=True, help="the other tree's src folder (the one holding driveopt/)")
    p.add_argument("--json", required=True, help="comparison file; each side's episodes are kept beside it (rerun to resume)")
    p.add_argument("--runs", nargs="+", default=list(RUNS), metavar="PLANNER:SCENARIO",
                   help=f"episodes to compare (default: {' '.join(RUNS)})")
    p.add_argument("--seed", type=seed, default=5, help="traffic and sampling seed of every run (default 5)")
    p.add_argument("--duration", type=duration, default=8.0, help="[s] of each episode (default 8)")
    p.add_argument("--current-config", metavar="JSON", help="planner-config overrides (JSON file) of this tree's side "
                   "alone, e.g. a default changed since named as it was at the baseline")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from driveopt.errors import DriveoptError
    from driveopt.experiments.closed_loop_ab import SideFailed, compare_trees, split_run
    from driveopt.registry import get_planner
    from driveopt.sim.scenarios import get_scenario

    baseline = Path(args.baseline_src)
    if not (baseline / "driveopt" / "__init__.py").is_file():
        raise UsageError(f"--baseline-src {baseline}: no driveopt package there (give the tree's src folder)")
    writable_file(args.json, "--json", (".json",))
    overrides = config_overrides(args.current_config) if args.current_config else None
    for run_name in args.runs:
        try:
            planner, scenario = split_run(run_name)
        except ValueError as exc:
            raise UsageError(f"--runs: {exc}") from None
        spec = get_planner(planner)  # unknown names: one line now, not a traceback in a side's process
        get_scenario(scenario)
        if overrides:
            if not spec.is_optimiser:
                raise UsageError(f"--current-config: {planner} plans with no configuration to override")
            try:
                spec.with_overrides(**overrides)
            except DriveoptError as exc:
                raise UsageError(f"--current-config: {exc}") from None
    out = Path(args.json)
    try:
        rows = compare_trees(baseline, out, args.runs, seed=args.seed, duration=args.duration,
                             current_config=overrides, log=lambda line: print(line, flush=True))
    except SideFailed as exc:
        raise UsageError(f"{exc}; its output above says why") from None
    except KeyboardInterrupt:
        raise KeyboardInterrupt(f"the finished episodes are kept beside {out}; rerun the same command to resume") from None
    for name, row in rows.items():
        seconds = row["compile_seconds"]
        verdict = "identical" if row["identical"] else f"DIFFERENT from step {row['first_difference_step']}"
        print(f"{name:32s} {verdict:28s} {row['steps']} steps; compile {seconds['baseline']:.1f} -> {seconds['current']:.1f} s")
    print(f"wrote {out}")
    return 0 if all(row["identical"] for row in rows.values()) else 1
