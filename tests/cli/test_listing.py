"""``driveopt scenarios`` and ``driveopt planners``: the tables they print, the planners grouped by family, and the
planner listing read from the registry's rows without building a planner or loading JAX."""

import json
import subprocess
import sys

from driveopt.cli.listing import planner_lines, scenario_lines
from driveopt.registry import FAMILIES, planner_rows
from driveopt.sim.scenarios import get_scenario, list_scenarios


def test_listings_print_the_tables(capsys):
    from driveopt.cli import main

    assert main(["scenarios"]) == 0
    assert capsys.readouterr().out.splitlines() == scenario_lines([get_scenario(name) for name in list_scenarios()])
    assert main(["planners"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines == planner_lines(planner_rows())
    assert lines[0] == f"{FAMILIES['driveopt']}:" and lines[1].startswith("  bilevel ")


def test_planners_are_listed_under_their_familys_heading_in_family_order():
    lines = planner_lines(planner_rows())
    headings = [line[:-1] for line in lines if line and not line.startswith(" ")]
    assert headings == list(FAMILIES.values())  # every family has planners, each heading once, in FAMILIES' order
    family = None
    listed = []
    for line in lines:
        if line and not line.startswith(" "):
            family = next(key for key, heading in FAMILIES.items() if f"{heading}:" == line)
        elif line:
            name, description = line.split(maxsplit=1)
            row = next(row for row in planner_rows() if row.name == name)
            assert (row.family, row.description) == (family, description)
            listed.append(name)
    assert sorted(listed) == sorted(row.name for row in planner_rows())
    assert {"idm", "dqn", "ppo"} == {row.name for row in planner_rows("reference")}
    assert {row.name for row in planner_rows("faithful")} == {row.name for row in planner_rows() if row.name.endswith("-faithful")}


def test_listing_the_planners_loads_no_jax_and_builds_no_planner():
    code = ("import sys\nfrom driveopt import registry\nimported = 'jax' in sys.modules\n"
            "from driveopt.cli import main\nmain(['planners'])\n"
            "print(__import__('json').dumps([imported, sorted(m for m in ('jax', 'flax', 'highway_env') if m in sys.modules), "
            "registry._built.cache_info().currsize]))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    assert "bilevel" in proc.stdout
    assert json.loads(proc.stdout.splitlines()[-1]) == [False, [], 0]
