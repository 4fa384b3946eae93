"""``driveopt scenarios`` and ``driveopt planners``: what can be named on the other commands."""

from __future__ import annotations

import argparse


def register(sub) -> None:
    sub.add_parser("scenarios", help="list scenarios").set_defaults(func=run_scenarios)
    sub.add_parser("planners", help="list planners").set_defaults(func=run_planners)


def run_scenarios(args: argparse.Namespace) -> int:
    from driveopt.sim.scenarios import get_scenario, list_scenarios

    width = max(len(name) for name in list_scenarios())
    for name in list_scenarios():
        s = get_scenario(name)
        lo, hi = s.target_speed_range
        print(f"{name:{width}s} {s.road:8s} lanes {s.lanes}  density {s.density:.1f}  limit {s.speed_limit:.0f} m/s  "
              f"targets {lo:g}-{hi:g} m/s  {s.duration:.0f} s")
    return 0


def run_planners(args: argparse.Namespace) -> int:
    from driveopt.registry import PLANNERS

    width = max(len(name) for name in PLANNERS)
    for spec in PLANNERS.values():
        print(f"{spec.name:{width}s}  {spec.description}")
    return 0
