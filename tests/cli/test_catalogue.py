"""The planners' light table (driveopt.cli.catalogue) is the registry's content, row for row, in its order."""

from driveopt.cli.catalogue import PLANNERS
from driveopt.cli.listing import planner_lines, scenario_lines
from driveopt.registry import PLANNERS as REGISTERED_PLANNERS
from driveopt.sim.scenarios import get_scenario, list_scenarios


def test_planner_table_matches_the_registry():
    expected = [(spec.name, spec.description) for spec in REGISTERED_PLANNERS.values()]
    rows = "\n".join(f"    {row!r}," for row in expected)
    assert list(PLANNERS) == expected, f"driveopt.cli.catalogue.PLANNERS is out of date; its rows are now:\n{rows}"


def test_listings_print_the_table(capsys):
    from driveopt.cli import main

    assert main(["scenarios"]) == 0
    assert capsys.readouterr().out.splitlines() == scenario_lines([get_scenario(name) for name in list_scenarios()])
    assert main(["planners"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines == planner_lines([(s.name, s.description) for s in REGISTERED_PLANNERS.values()])
    assert lines[0].startswith("bilevel ") and len(lines) == len(REGISTERED_PLANNERS)
