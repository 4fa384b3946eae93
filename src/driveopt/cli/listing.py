"""``driveopt scenarios`` and ``driveopt planners``: what can be named on the other commands.

Neither imports JAX, highway-env or Flax: scenarios come from their registry (:mod:`driveopt.sim.scenarios`), planners
from the rows of theirs (:mod:`driveopt.registry`), whose specs are built only when a planner is asked for.
"""

from __future__ import annotations

import argparse

from driveopt.registry import FAMILIES, PlannerRow, planner_rows


def register(sub) -> None:
    sub.add_parser("scenarios", help="list scenarios").set_defaults(func=run_scenarios)
    sub.add_parser("planners", help="list planners").set_defaults(func=run_planners)


def scenario_lines(rows: list) -> list[str]:
    """One line per scenario (:class:`driveopt.sim.scenarios.Scenario`): name, road, lanes, density, neighbours' speed
    limit [m/s], their target speeds [m/s], episode length [s]."""
    width = max(len(row.name) for row in rows)
    return [f"{r.name:{width}s} {r.road:8s} lanes {r.lanes}  density {r.density:.1f}  limit {r.speed_limit:.0f} m/s  "
            f"targets {r.target_speed_range[0]:g}-{r.target_speed_range[1]:g} m/s  {r.duration:.0f} s" for r in rows]


def planner_lines(rows: tuple[PlannerRow, ...]) -> list[str]:
    """The planners grouped by family (:data:`driveopt.registry.FAMILIES`, in its order): a heading line per family,
    then one indented line per planner with its name and one-line description; a blank line between families."""
    width = max(len(row.name) for row in rows)
    lines: list[str] = []
    for family, heading in FAMILIES.items():
        members = [row for row in rows if row.family == family]
        if members:
            lines += [""] * bool(lines) + [f"{heading}:"] + [f"  {row.name:{width}s}  {row.description}" for row in members]
    return lines


def run_scenarios(args: argparse.Namespace) -> int:
    from driveopt.sim.scenarios import get_scenario, list_scenarios

    print("\n".join(scenario_lines([get_scenario(name) for name in list_scenarios()])))
    return 0


def run_planners(args: argparse.Namespace) -> int:
    print("\n".join(planner_lines(planner_rows())))
    return 0
