"""``driveopt bench``: scenarios x planners x seeds x episodes, resumable, with summary table and plots.

With ``--lockstep E`` the episodes of each planner step E at a time, one planning call for all of them per policy step
(:mod:`driveopt.experiments.lockstep`). Names, options and seeds are checked before the output folder is touched
(``BenchSpec.check``); a folder another run is writing is refused at once. Ctrl-C stops at once with ``driveopt:
interrupted: N episodes kept in OUT; ...`` and status 130.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from driveopt.cli.common import config_overrides, positive_int, seed
from driveopt.cli.parser import duration, latency


def register(sub) -> None:
    p = sub.add_parser("bench", help="scenarios x planners x seeds x episodes; resumable; summary table and plots")
    p.add_argument("--scenarios", nargs="+", default=["four-lane-d3.0", "two-lane-d2.5"],
                   help="scenario names (see `driveopt scenarios`)")
    p.add_argument("--planners", nargs="+", default=["bilevel", "vanilla", "grid", "random", "batch", "idm"],
                   help="planner names (see `driveopt planners`)")
    p.add_argument("--seeds", nargs="+", type=seed, default=[42],
                   help="traffic seeds (episode e of seed s drives traffic seed s x 100003 + e, which must fit in 32 bits)")
    p.add_argument("--episodes", type=positive_int, default=50, help="episodes per scenario, planner and seed")
    p.add_argument("--episode-list", nargs="+", type=int, metavar="E",
                   help="run only these episode indices (each below --episodes), e.g. an A/B on the episodes that collided")
    p.add_argument("--duration", type=duration, help="episode length [s] (default: the scenario's)")
    p.add_argument("--samples", type=positive_int, help="override the optimisers' samples per iteration (not vanilla's single sample; default: each planner's)")
    p.add_argument("--weights", help="learned-prior checkpoint for the cvae planner, or policy file for dqn/ppo (default: shipped weights)")
    p.add_argument("--filter-weights", help="learned safety-filter checkpoint for every optimiser (recorded with --config)")
    p.add_argument("--config", help="planner config overrides applied to every optimiser, JSON (nested sections)")
    p.add_argument("--replan-every", type=positive_int, help="policy periods each plan is executed open-loop (P1: 5; default 1)")
    p.add_argument("--latency", type=latency, metavar="sync|measured|MS",
                   help="sync (default): the simulator waits for every plan; measured: the car keeps executing the "
                        "previous plan while one is computed, which takes effect after its measured time rounded up "
                        "to policy periods; MS: a fixed compute time [ms] instead (deterministic)")
    p.add_argument("--scenario-config", help="JSON file of scenario-field overrides applied to every scenario")
    p.add_argument("--workers", type=positive_int, help="parallel episodes (default: the CPUs it may use, its affinity)")
    p.add_argument("--lockstep", type=positive_int, metavar="E",
                   help="step E episodes of each planner together, one planning call for all per policy step (one "
                        "process, cells of jobs in --workers processes or as Ray tasks; optimisers with synchronous latency "
                        "only)")
    p.add_argument("--backend", choices=["local", "ray"], default="local",
                   help="local processes, or Ray (RAY_ADDRESS names the cluster; needs driveopt[ray])")
    p.add_argument("--out", default="out/bench", help="output directory (rerun to resume)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from driveopt.experiments.bench import BenchSpec, run_bench
    from driveopt.experiments.store import load_records
    from driveopt.experiments.summary import markdown_table
    from driveopt.sim.scenarios import load_overrides

    scenario = load_overrides(args.scenario_config) if args.scenario_config else None
    given = (("duration", args.duration), ("samples", args.samples), ("weights", args.weights),
             ("config", config_overrides(args.config, args.filter_weights) or None), ("replan_every", args.replan_every),
             ("latency", args.latency),
             ("scenario", scenario))
    options = {k: v for k, v in given if v is not None}
    spec = BenchSpec(tuple(args.scenarios), tuple(args.planners), tuple(args.seeds), args.episodes, options,
                     tuple(args.episode_list or ()))
    try:
        rows = run_bench(spec, args.out, workers=args.workers, backend=args.backend, lockstep=args.lockstep)
    except KeyboardInterrupt:
        kept = len(load_records(Path(args.out) / "episodes.jsonl"))
        raise KeyboardInterrupt(f"{kept} episodes kept in {args.out}; rerun the same command to resume") from None
    print(markdown_table(rows))
    print(f"wrote {args.out}/episodes.jsonl, summary.csv, summary.md, summary.json, summary.png")
    return 0
