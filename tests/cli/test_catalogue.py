"""The listings' light table (driveopt.cli.catalogue) is the registries' content, row for row, in their order."""

from driveopt.cli.catalogue import PLANNERS, SCENARIOS, ScenarioLine
from driveopt.cli.listing import planner_lines, scenario_lines
from driveopt.registry import PLANNERS as REGISTERED_PLANNERS
from driveopt.sim.scenarios import get_scenario, list_scenarios


def _registered_scenarios() -> list[ScenarioLine]:
    rows = []
    for name in list_scenarios():
        s = get_scenario(name)
        rows.append(ScenarioLine(name, s.road, s.lanes, s.density, s.speed_limit, tuple(s.target_speed_range), s.duration))
    return rows


def test_scenario_table_matches_the_registry():
    expected = _registered_scenarios()
    rows = "\n".join(f"    {row!r}," for row in expected)
    assert list(SCENARIOS) == expected, f"driveopt.cli.catalogue.SCENARIOS is out of date; its rows are now:\n{rows}"


def test_planner_table_matches_the_registry():
    expected = [(spec.name, spec.description) for spec in REGISTERED_PLANNERS.values()]
    rows = "\n".join(f"    {row!r}," for row in expected)
    assert list(PLANNERS) == expected, f"driveopt.cli.catalogue.PLANNERS is out of date; its rows are now:\n{rows}"


def test_listings_print_the_table(capsys):
    from driveopt.cli import main

    assert main(["scenarios"]) == 0
    assert capsys.readouterr().out.splitlines() == scenario_lines(_registered_scenarios())
    assert main(["planners"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines == planner_lines([(s.name, s.description) for s in REGISTERED_PLANNERS.values()])
    assert lines[0].startswith("bilevel ") and len(lines) == len(REGISTERED_PLANNERS)
