"""``driveopt scenarios`` and ``driveopt planners``: what can be named on the other commands.

Neither imports JAX, highway-env or Flax: scenarios come from their registry (:mod:`driveopt.sim.scenarios`), planners
from :mod:`driveopt.cli.catalogue`, whose rows the tests keep equal to the planner registry's.
"""

from __future__ import annotations

import argparse

from driveopt.cli.catalogue import PLANNERS


def register(sub) -> None:
    sub.add_parser("scenarios", help="list scenarios").set_defaults(func=run_scenarios)
    sub.add_parser("planners", help="list planners").set_defaults(func=run_planners)


def scenario_lines(rows: list) -> list[str]:
    """One line per scenario (:class:`driveopt.sim.scenarios.Scenario`): name, road, lanes, density, neighbours' speed
    limit [m/s], their target speeds [m/s], episode length [s]."""
    width = max(len(row.name) for row in rows)
    return [f"{r.name:{width}s} {r.road:8s} lanes {r.lanes}  density {r.density:.1f}  limit {r.speed_limit:.0f} m/s  "
            f"targets {r.target_speed_range[0]:g}-{r.target_speed_range[1]:g} m/s  {r.duration:.0f} s" for r in rows]


def planner_lines(rows: list[tuple[str, str]]) -> list[str]:
    """One line per planner: its name and one-line description."""
    width = max(len(name) for name, _ in rows)
    return [f"{name:{width}s}  {description}" for name, description in rows]


def run_scenarios(args: argparse.Namespace) -> int:
    from driveopt.sim.scenarios import get_scenario, list_scenarios

    print("\n".join(scenario_lines([get_scenario(name) for name in list_scenarios()])))
    return 0


def run_planners(args: argparse.Namespace) -> int:
    print("\n".join(planner_lines(list(PLANNERS))))
    return 0
