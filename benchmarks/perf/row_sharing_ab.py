"""Projecting a batch's repeated rows once (``DistinctRows``) against projecting every row (``EveryRow``), on
closed-loop states: the same picks, and how much faster.

    python benchmarks/perf/row_sharing_ab.py --json out/row-sharing.json [--planner vqvae-filter] [--samples N]
        [--scenario p2-four-lane-d3.0] [--episodes 3] [--every 10] [--steps 300] [--seed 1000]

States: ``--episodes`` episodes of ``--scenario`` (seeds ``--seed``, ``--seed`` + 1, ...) driven by ``bilevel``, the
planning problem of every ``--every``-th step up to ``--steps``. At each state the ``--planner`` (a registered
optimiser that shares rows, at its own sample count or ``--samples``; its prior and filter for the road) plans once
with each row sharing, with the same key; recorded per state:
whether the two picked the same set-points, their statuses, costs and feasible rows, the largest difference between
their rows' residuals, how many distinct rows the batch had, and each call's time [ms]. The timed calls come after one
compiling call per side; the two sides alternate per state. Results are written after every state; a rerun with
the same arguments resumes. The machine's load average is recorded before and after.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

from driveopt import planner
from driveopt.cli.common import positive_int
from driveopt.experiments.rollout import Rollout
from driveopt.files import write_json
from driveopt.registry import get_optimiser, get_planner
from driveopt.row_sharing import DistinctRows, EveryRow, distinct_rows
from driveopt.sim import get_scenario

if __package__ in (None, ""):  # run as a file: the repository root on the path, for the package import below
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks.perf.call_profile import machine  # noqa: E402


def states(scenario_name: str, episodes: int, every: int, steps: int, seed: int) -> list:
    """The planning problems ``bilevel`` faced at every ``every``-th step of each episode, in order."""
    scenario = get_scenario(scenario_name)
    problems = []
    for episode in range(episodes):
        for number, step in enumerate(Rollout(scenario, get_planner("bilevel").driver(), seed + episode)):
            if number % every == 0:
                problems.append(step.decision.problem)
            if number + 1 >= steps:
                break
    return problems


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", type=Path, required=True)
    parser.add_argument("--planner", default="vqvae-filter")
    parser.add_argument("--samples", type=positive_int, help="samples per batch (default: the planner's own)")
    parser.add_argument("--scenario", default="p2-four-lane-d3.0")
    parser.add_argument("--episodes", type=positive_int, default=3)
    parser.add_argument("--every", type=positive_int, default=10, help="[steps] between recorded states")
    parser.add_argument("--steps", type=positive_int, default=300, help="steps driven per episode")
    parser.add_argument("--seed", type=int, default=1000)
    args = parser.parse_args(argv)
    spec = get_optimiser(args.planner)
    spec = spec if args.samples is None else spec.with_samples(args.samples)
    if not isinstance(spec.method.row_sharing, DistinctRows):
        parser.error(f"{args.planner} projects every row (row_sharing {spec.method.row_sharing}); pick a planner that shares rows")

    arguments = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items() if k != "json"}
    report = {"arguments": arguments, "machine": machine(), "load_before": os.getloadavg(), "states": []}
    if args.json.exists():
        previous = json.loads(args.json.read_text())
        if previous.get("arguments") != arguments:
            parser.error(f"{args.json} holds a run with other arguments: {previous.get('arguments')}")
        report["states"] = previous["states"]
    problems = states(args.scenario, args.episodes, args.every, args.steps, args.seed)
    lanes = get_scenario(args.scenario).lanes
    prior, safety_filter = spec.prior(lanes), spec.safety_filter(lanes)
    sides = {"every_row": EveryRow(), "distinct_rows": spec.method.row_sharing}

    def call(problem, key: int, sharing):
        start = time.perf_counter()
        result = planner.plan(problem, spec.config, key=jax.random.PRNGKey(key), prior=prior, safety_filter=safety_filter,
                              method=dataclasses.replace(spec.method, row_sharing=sharing))
        return result, 1e3 * (time.perf_counter() - start)

    for sharing in sides.values():  # compile both before timing either
        call(problems[0], 0, sharing)
    for index in range(len(report["states"]), len(problems)):
        problem = problems[index]
        order = list(sides.items()) if index % 2 == 0 else list(sides.items())[::-1]
        results, times = {}, {}
        for name, sharing in order:
            results[name], times[name] = call(problem, index, sharing)
        every, shared = results["every_row"], results["distinct_rows"]
        rows = np.asarray(every.first.qp_coeffs)  # the boundary values are shared by the rows of these planners
        report["states"].append({
            "same_pick": bool(np.array_equal(every.setpoints, shared.setpoints)),
            "status": [every.status.name, shared.status.name],
            "cost": [float(every.costs["total"]), float(shared.costs["total"])],
            "feasible_rows": [int(every.history.num_feasible[0]), int(shared.history.num_feasible[0])],
            "largest_residual_difference": float(np.max(np.abs(every.first.residual - shared.first.residual))),
            "rows": int(rows.shape[0]), "distinct_rows": int(distinct_rows(rows)[1]),
            "plan_ms": [times["every_row"], times["distinct_rows"]],
        })
        write_json(args.json, report)
        print(f"state {index + 1}/{len(problems)}: {report['states'][-1]['distinct_rows']} distinct rows, "
              f"{times['every_row']:.0f} -> {times['distinct_rows']:.0f} ms", flush=True)
    done = report["states"]
    report["load_after"] = os.getloadavg()
    plan_ms = np.array([s["plan_ms"] for s in done])
    report["summary"] = {
        "states": len(done), "same_pick": sum(s["same_pick"] for s in done),
        "same_status": sum(s["status"][0] == s["status"][1] for s in done),
        "distinct_rows_median_p95_max": [float(np.median([s["distinct_rows"] for s in done])),
                                         float(np.percentile([s["distinct_rows"] for s in done], 95)),
                                         max(s["distinct_rows"] for s in done)],
        "plan_ms_median": np.median(plan_ms, axis=0).tolist(), "plan_ms_p95": np.percentile(plan_ms, 95, axis=0).tolist(),
    }
    write_json(args.json, report)
    print(json.dumps(report["summary"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
