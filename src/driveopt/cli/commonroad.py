"""``driveopt commonroad``: driveopt's planners (and FISS's) on a folder of CommonRoad scenarios, judged by one
evaluator (:mod:`driveopt.commonroad`); needs the ``commonroad`` extra. Resumable: rerun the same command. Ctrl-C stops
at once with ``driveopt: interrupted: N runs kept in OUT; ...`` and status 130."""

from __future__ import annotations

import argparse
from pathlib import Path

from driveopt.cli.common import positive_int
from driveopt.commonroad import EXECUTIONS


def register(sub) -> None:
    p = sub.add_parser("commonroad", help="planners on CommonRoad scenarios (driveopt[commonroad]); resumable JSONL")
    p.add_argument("--scenarios", required=True, help="folder of CommonRoad .xml scenarios")
    p.add_argument("--planners", nargs="+", default=["bilevel"],
                   help="registered optimisers (bilevel, ...) and FISS's fiss_plus, fiss, fop_plus, fop")
    p.add_argument("--samples", type=positive_int, help="override the optimisers' samples per iteration")
    p.add_argument("--execution", choices=EXECUTIONS, default="perfect",
                   help="how the ego moves between time steps: perfect: where its plan is one time step later (FISS's "
                   "benchmark's model); tracked: driveopt's kinematic bicycle following the plan with driveopt's "
                   "tracker (driveopt's planners only); one OUT folder holds one model")
    p.add_argument("--out", default="out/commonroad", help="output folder (rerun to resume)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from driveopt.commonroad import require
    from driveopt.commonroad.bench import RUNS_FILE, check_execution, load_runs, run as run_folder, scenario_files
    from driveopt.commonroad.fiss import PLANNERS as FISS
    from driveopt.errors import DriveoptError

    check_execution(args.execution, tuple(args.planners), load_runs(Path(args.out) / RUNS_FILE), args.out)
    require(fiss=any(p in FISS for p in args.planners))
    from driveopt.registry import get_planner

    scenario_files(args.scenarios)
    for planner in args.planners:
        if planner not in FISS and not get_planner(planner).is_optimiser:
            raise DriveoptError(f"planner '{planner}' does not plan with the optimiser; commonroad runs optimisers and "
                                f"{', '.join(FISS)}")
    try:
        records = run_folder(args.scenarios, tuple(args.planners), args.out, samples=args.samples, execution=args.execution)
    except KeyboardInterrupt:
        kept = len(load_runs(Path(args.out) / RUNS_FILE))
        raise KeyboardInterrupt(f"{kept} runs kept in {args.out}; rerun the same command to resume") from None
    print((Path(args.out) / "summary.md").read_text(), end="")
    print(f"wrote {args.out}/{RUNS_FILE}, summary.md, trajectories/ ({len(records)} runs)")
    return 0
