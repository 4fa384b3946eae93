"""Projection settings against a planner's own on recorded closed-loop states: residuals, the chosen behaviour, time.

    python benchmarks/perf/settings_offline.py --set max_iterations=12 --set anderson_window=4 --json OUT
        [--planner bilevel] [--samples N] [--scenarios four-lane-d3.0 two-lane-d2.5] [--episodes 2] [--every 4]
        [--steps 320] [--seed 1000] [--save-states STATES.npz]

States: ``--episodes`` episodes of each scenario (seeds ``--seed``, ``--seed`` + 1, ...) driven by ``bilevel``, the
planning problem of every ``--every``-th step up to ``--steps``. At each state the ``--planner`` (a registered
optimiser, at its own sample count or ``--samples``) plans three times: with its own configuration and with the
``--set`` projection fields changed, both with the same key, and with its own configuration under another key (how
much a pick moves with the key alone, the yardstick for the changed side). Recorded per state and side: the status,
the pick's total residual and cost, its four speed set-points [m/s] and the lanes of its four lateral set-points, the
last sampler iteration's median and smallest batch residual and feasible rows, and the call's time [ms] (the sides
alternate in order from state to state, after one compiling call each). Results are written after every state; a
rerun with the same arguments resumes. The machine's load average is recorded before and after. ``--save-states``
also writes the recorded states (:func:`save_states`; the tests' ``tests/core/closed-loop-states.npz`` was written so,
with ``--episodes 1 --every 40``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

from driveopt import planner
from driveopt.cli.common import positive_int
from driveopt.files import write_json
from driveopt.registry import get_optimiser
from driveopt.sim import get_scenario

if __package__ in (None, ""):  # run as a file: the repository root on the path, for the package import below
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks.perf.call_profile import machine  # noqa: E402
from benchmarks.perf.op_count import _setting  # noqa: E402
from benchmarks.perf.row_sharing_ab import states  # noqa: E402

OTHER_KEY = 1_000_000  # the yardstick side's key offset


def save_states(path: Path, problems: list) -> None:
    """(scenario, PlanningProblem) pairs as one compressed ``.npz``: ``scenarios`` and each field as ``"{i}.{field}"``."""
    arrays = {f"{i}.{field}": np.asarray(value) for i, (_, problem) in enumerate(problems)
              for field, value in problem._asdict().items()}
    np.savez_compressed(path, scenarios=np.array([name for name, _ in problems]), **arrays)


def load_states(path: Path) -> list:
    """The (scenario, PlanningProblem) pairs :func:`save_states` wrote; a file from before the road's curvature became a
    table of cells (one number per problem) gets that number's magnitude in every cell, and one from before a field
    existed that field's value then (``recorded_before``)."""
    from driveopt.problem import NO_PULL, PlanningProblem
    from driveopt.scene import CURVATURE_CELLS

    recorded_before = {"pull_band": NO_PULL,  # a route's pull band: none
                       "road_origin": 0.0,  # the curvature's origin: the line y = 0
                       "slowing": 0.0, "slowing_from": 0.0}  # the speed reference: v_des from the first node

    def field_of(data, i: int, field: str) -> np.ndarray:
        if f"{i}.{field}" not in data and field in recorded_before:
            return np.asarray(recorded_before[field], dtype=np.float32)
        value = data[f"{i}.{field}"]
        if field == "road_curvature" and value.ndim == 0:
            return np.full(CURVATURE_CELLS, abs(value), dtype=value.dtype)
        return value

    with np.load(path) as data:
        return [(str(name), PlanningProblem(**{field: field_of(data, i, field) for field in PlanningProblem._fields}))
                for i, name in enumerate(data["scenarios"])]


def lanes(problem, lateral: np.ndarray) -> list[int]:
    """Index of the lane whose centre is nearest each lateral set-point [m]."""
    index = np.rint((lateral - float(problem.lane_center0)) / float(problem.lane_width))
    return [int(i) for i in np.clip(index, 0, int(problem.num_lanes) - 1)]


def pick(problem, result, ms: float) -> dict:
    setpoints = np.asarray(result.setpoints)
    return {"status": result.status.name, "residual": float(result.residuals["total"]),
            "cost": float(result.costs["total"]), "speeds": [round(float(v), 3) for v in setpoints[:4]],
            "lanes": lanes(problem, setpoints[4:]), "median_residual": float(result.history.median_residual[-1]),
            "min_residual": float(result.history.min_residual[-1]),
            "feasible_rows": int(result.history.num_feasible[-1]), "ms": round(ms, 3)}


def agreement(records: list[dict], side: str) -> dict:
    """How ``side``'s picks compare with the planner's own pick of the same key."""
    same_lanes = [r[side]["lanes"] == r["own"]["lanes"] for r in records]
    last_lane = [r[side]["lanes"][-1] == r["own"]["lanes"][-1] for r in records]
    speed_gap = [max(abs(a - b) for a, b in zip(r[side]["speeds"], r["own"]["speeds"])) for r in records]
    return {"same_lanes": float(np.mean(same_lanes)), "same_last_lane": float(np.mean(last_lane)),
            "speed_gap_median": float(np.median(speed_gap)), "speed_gap_p90": float(np.percentile(speed_gap, 90))}


def side_summary(records: list[dict], side: str) -> dict:
    def stat(field):
        values = np.array([r[side][field] for r in records], dtype=float)
        return {"median": float(np.median(values)), "p90": float(np.percentile(values, 90))}

    return {"success": float(np.mean([r[side]["status"] == "SUCCESS" for r in records])),
            **{field: stat(field) for field in ("residual", "median_residual", "min_residual", "feasible_rows", "ms")}}


def summarise(records: list[dict]) -> dict:
    sides = ("own", "changed", "own_other_key")
    return {"states": len(records), **{side: side_summary(records, side) for side in sides},
            "against_own": {side: agreement(records, side) for side in sides[1:]},
            "both_success_or_not": float(np.mean([(r["own"]["status"] == "SUCCESS") == (r["changed"]["status"] == "SUCCESS")
                                                  for r in records]))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", type=Path, required=True)
    parser.add_argument("--set", type=_setting, action="append", required=True, metavar="FIELD=VALUE",
                        help="a projection field of the changed side (repeatable)")
    parser.add_argument("--planner", default="bilevel")
    parser.add_argument("--samples", type=positive_int, help="samples per batch (default: the planner's own)")
    parser.add_argument("--scenarios", nargs="+", default=["four-lane-d3.0", "two-lane-d2.5"])
    parser.add_argument("--episodes", type=positive_int, default=2, help="episodes per scenario")
    parser.add_argument("--every", type=positive_int, default=4, help="[steps] between recorded states")
    parser.add_argument("--steps", type=positive_int, default=320, help="steps driven per episode")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--save-states", type=Path, help="also write the recorded states here (.npz)")
    args = parser.parse_args(argv)
    own = get_optimiser(args.planner)
    own = own if args.samples is None else own.with_samples(args.samples)
    changed = own.with_overrides(projection=dict(args.set))  # a bad field or value fails here, before any driving

    arguments = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items() if k not in ("json", "save_states")}
    report = {"command": "python benchmarks/perf/settings_offline.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "arguments": arguments, "machine": machine(), "load_before": os.getloadavg(), "states": []}
    if args.json.exists():
        previous = json.loads(args.json.read_text())
        if previous.get("arguments") != arguments:
            parser.error(f"{args.json} holds a run with other arguments: {previous.get('arguments')}")
        report["states"] = previous["states"]
    problems = [(name, problem) for name in args.scenarios
                for problem in states(name, args.episodes, args.every, args.steps, args.seed)]
    if args.save_states:
        save_states(args.save_states, problems)
    strategies = {name: (own.prior(get_scenario(name).lanes), own.safety_filter(get_scenario(name).lanes))
                  for name in args.scenarios}
    sides = {"own": (own.config, 0), "changed": (changed.config, 0), "own_other_key": (own.config, OTHER_KEY)}

    def call(scenario: str, problem, config, key: int):
        prior, safety_filter = strategies[scenario]
        start = time.perf_counter()
        result = planner.plan(problem, config, key=jax.random.PRNGKey(key), prior=prior, safety_filter=safety_filter,
                              method=own.method)
        return result, 1e3 * (time.perf_counter() - start)

    for config, _ in list(sides.values())[:2]:  # compile both before timing either
        call(*problems[0], config, 0)
    for index in range(len(report["states"]), len(problems)):
        scenario, problem = problems[index]
        order = list(sides.items()) if index % 2 == 0 else list(sides.items())[::-1]
        record = {"scenario": scenario}
        for name, (config, offset) in order:
            result, ms = call(scenario, problem, config, index + offset)
            record[name] = pick(problem, result, ms)
        report["states"].append(record)
        write_json(args.json, report)
        print(f"state {index + 1}/{len(problems)} {scenario}: " + ", ".join(
            f"{name} {record[name]['status']} {record[name]['ms']:.0f} ms" for name in sides), flush=True)
    report["load_after"] = os.getloadavg()
    report["summary"] = {"all": summarise(report["states"]),
                         **{name: summarise([r for r in report["states"] if r["scenario"] == name]) for name in args.scenarios}}
    write_json(args.json, report)
    print(json.dumps(report["summary"]["all"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
