"""``driveopt scenarios`` and ``driveopt planners``: what can be named on the other commands.

Both print from :mod:`driveopt.cli.catalogue` (no JAX, highway-env or Flax is imported), whose rows the tests keep equal
to the registries'.
"""

from __future__ import annotations

import argparse

from driveopt.cli.catalogue import PLANNERS, SCENARIOS, ScenarioLine


def register(sub) -> None:
    sub.add_parser("scenarios", help="list scenarios").set_defaults(func=run_scenarios)
    sub.add_parser("planners", help="list planners").set_defaults(func=run_planners)


def scenario_lines(rows: list[ScenarioLine]) -> list[str]:
    """One line per scenario: name, road, lanes, density, neighbours' speed limit [m/s], their target speeds [m/s],
    episode length [s]."""
    width = max(len(row.name) for row in rows)
    return [f"{r.name:{width}s} {r.road:8s} lanes {r.lanes}  density {r.density:.1f}  limit {r.speed_limit:.0f} m/s  "
            f"targets {r.target_speeds[0]:g}-{r.target_speeds[1]:g} m/s  {r.duration:.0f} s" for r in rows]


def planner_lines(rows: list[tuple[str, str]]) -> list[str]:
    """One line per planner: its name and one-line description."""
    width = max(len(name) for name, _ in rows)
    return [f"{name:{width}s}  {description}" for name, description in rows]


def run_scenarios(args: argparse.Namespace) -> int:
    print("\n".join(scenario_lines(list(SCENARIOS))))
    return 0


def run_planners(args: argparse.Namespace) -> int:
    print("\n".join(planner_lines(list(PLANNERS))))
    return 0
