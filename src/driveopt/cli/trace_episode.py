"""``driveopt trace-episode``: the last seconds of one bench episode, policy step by policy step.

Replays bench episode ``--episode`` of ``--seed`` (the traffic ``driveopt bench`` drove it in) with ``--planner`` and
prints the episode's summary as one JSON line, then one line per policy step of the last ``--last`` seconds (the
approach to a collision when there is one): the ego's state, the plan and the cars nearby
(:mod:`driveopt.experiments.trace_episode`). ``--json`` writes the summary and every step's row. ``--samples``,
``--config``, ``--weights`` and ``--filter-weights`` are bench's, so that the replay plans as the bench episode did;
bind it to the CPUs the bench worker had (``taskset``) to replay it step for step.
"""

from __future__ import annotations

import argparse
import json

from driveopt.cli.common import config_overrides, non_negative_int, positive_int, seed, writable_file
from driveopt.cli.parser import duration


def _seconds(text: str) -> float:
    """Argument type of ``--last``: a positive finite number of seconds."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not 0.0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive number of seconds, got {text}")
    return value


def register(sub) -> None:
    p = sub.add_parser("trace-episode", help="replay one bench episode and print its last seconds step by step")
    p.add_argument("--scenario", required=True, help="scenario name of the bench run (see `driveopt scenarios`)")
    p.add_argument("--planner", required=True, help="planner name of the bench run (see `driveopt planners`)")
    p.add_argument("--episode", type=non_negative_int, required=True, help="bench episode number (0-based)")
    p.add_argument("--seed", type=seed, default=42, help="bench seed (default 42)")
    p.add_argument("--samples", type=positive_int, default=250, help="samples per sampler iteration (default 250)")
    p.add_argument("--config", help="planner-config overrides (JSON file, as for driveopt bench --config)")
    p.add_argument("--weights", help="learned prior or policy checkpoint (default: the shipped weights)")
    p.add_argument("--filter-weights", help="learned safety-filter checkpoint (as for driveopt bench)")
    p.add_argument("--last", type=_seconds, default=3.0, help="[s] how much of the episode's end to print (default 3)")
    p.add_argument("--duration", type=duration, help="[s] stop the episode here (default: the scenario's)")
    p.add_argument("--json", help="write the summary and every step's row here")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from driveopt.experiments.trace_episode import step_line, trace
    from driveopt.files import write_json

    writable_file(args.json, "--json")
    overrides = config_overrides(args.config, args.filter_weights) or None
    summary, rows = trace(args.scenario, args.planner, args.episode, seed=args.seed, samples=args.samples,
                          overrides=overrides, duration=args.duration, weights=args.weights)
    print(json.dumps(summary))
    shown = [row for row in rows if row["t"] >= rows[-1]["t"] - args.last] if rows else []
    for row in shown:
        print(step_line(row))
    if args.json:
        write_json(args.json, {"summary": summary, "steps": rows}, indent=None)
        print(f"wrote {args.json}")
    return 0
