"""How many samples of each planner's first batch project to a feasible plan at one closed-loop state.

    python benchmarks/studies/first_batch_feasibility.py --json out/first_batch.json \
        [--scenario four-lane-d3.0] [--seed 42] [--episode 15] [--drive cvae] [--time 5.0] \
        [--planners cvae bilevel-p1 bilevel cvae-mix] [--samples 250] [--keys 20]

Drives bench episode ``--episode`` of ``--seed`` (the same traffic as ``driveopt bench``) with the
``--drive`` planner up to ``--time`` [s], then plans from that state with every planner of
``--planners`` under ``--keys`` sampling keys (first call: no warm start). Reports, per planner, the
median number of feasible samples in the first and last sampler iteration (the two stopping plans
not counted) and the share of keys whose chosen plan keeps moving (last speed set-point over
1 m/s). Used to trace the stalls of the pure CVAE start (README, "Learned warm start").
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import numpy as np

from driveopt.drivers.optimiser import adapt_to_vehicle
from driveopt.errors import DriveoptError
from driveopt.experiments.rollout import Rollout
from driveopt.experiments.store import JobKey
from driveopt.files import write_json
from driveopt.planner import PlanStatus, RowKind, plan
from driveopt.registry import get_planner
from driveopt.sim import BicycleModel, get_scenario, make_env

MOVING_SPEED = 1.0  # [m/s] last speed set-point above which a chosen plan counts as moving
def state_at(scenario, drive: str, env_seed: int, samples: int, time_s: float):
    """The planning problem the ``drive`` planner faced at ``time_s`` [s] of the episode."""
    calls = int(round(time_s * scenario.policy_frequency)) + 1
    rollout = Rollout(scenario, get_planner(drive).with_samples(samples).driver(), env_seed)
    for number, step in enumerate(rollout, start=1):
        if number == calls:
            return step.decision.problem
    raise SystemExit(f"first_batch_feasibility: error: the episode ended at {rollout.episode.sim_duration:.1f} s, before --time {time_s}")


def feasible_samples(snapshot, tolerance: float) -> int:
    """Sampled rows (not the appended stops or previous plan) within the residual tolerance."""
    sampled = np.asarray(snapshot.kind) == RowKind.SAMPLE
    return int(np.sum(np.asarray(snapshot.residual)[sampled] < tolerance))


def feasibility(problem, scenario, model, name: str, samples: int, keys: int) -> dict:
    spec = get_planner(name).with_samples(samples)
    config = adapt_to_vehicle(spec.config, model)
    prior = spec.prior(scenario.lanes)
    tolerance = config.sampler.residual_tolerance
    first, last, moving = [], [], []
    for k in range(keys):
        result = plan(problem, config, key=jax.random.PRNGKey(k), prior=prior)
        first.append(feasible_samples(result.first, tolerance))
        last.append(feasible_samples(result.last, tolerance))
        moving.append(bool(result.status == PlanStatus.SUCCESS and result.setpoints[3] > MOVING_SPEED))
    return {"planner": name, "samples": samples, "keys": keys,
            "feasible_first_median": float(np.median(first)), "feasible_last_median": float(np.median(last)),
            "moving_share": float(np.mean(moving))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", default="out/first_batch_feasibility.json")
    parser.add_argument("--scenario", default="four-lane-d3.0")
    parser.add_argument("--seed", type=int, default=42)
    parser.add_argument("--episode", type=int, default=15)
    parser.add_argument("--drive", default="cvae", help="planner that drives up to --time")
    parser.add_argument("--time", type=float, default=5.0, help="[s] state to plan from")
    parser.add_argument("--planners", nargs="+", default=["cvae", "bilevel-p1", "bilevel", "cvae-mix"])
    parser.add_argument("--samples", type=int, default=250)
    parser.add_argument("--keys", type=int, default=20)
    args = parser.parse_args(argv)
    if args.time <= 0 or args.keys < 1 or args.samples < 1:
        parser.error("--time must be > 0, --keys and --samples >= 1")
    try:
        scenario = get_scenario(args.scenario)
        for name in (args.drive, *args.planners):
            get_planner(name)
    except DriveoptError as exc:
        parser.error(str(exc))
    env = make_env(scenario)
    env.reset(seed=0)
    model = BicycleModel.from_env(env)
    env.close()
    env_seed = JobKey(args.scenario, args.drive, args.seed, args.episode).env_seed
    problem = state_at(scenario, args.drive, env_seed, args.samples, args.time)
    report = {"scenario": args.scenario, "seed": args.seed, "episode": args.episode, "env_seed": env_seed,
              "drive": args.drive, "time_s": args.time, "results": []}
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    for name in args.planners:
        report["results"].append(feasibility(problem, scenario, model, name, args.samples, args.keys))
        write_json(path, report)
        r = report["results"][-1]
        print(f"{name:>12}: feasible samples, first batch {r['feasible_first_median']:.0f} / {args.samples}, "
              f"last {r['feasible_last_median']:.0f}; chosen plan moving for {100 * r['moving_share']:.0f}% of keys")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
