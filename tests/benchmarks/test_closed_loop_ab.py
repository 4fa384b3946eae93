"""benchmarks/closed_loop_ab.py: the same episodes under two source trees, compared step by step."""

from __future__ import annotations

import json
from pathlib import Path

import benchmark_scripts
import pytest

SRC = Path(__file__).resolve().parents[2] / "src"


@pytest.fixture(scope="module")
def ab():
    return benchmark_scripts.load("closed_loop_ab")


def _episode(speeds, lateral, statuses=None):
    return {"speeds": speeds, "lateral": lateral, "statuses": statuses or {"SUCCESS": len(speeds)}, "compile_seconds": 1.0}


def test_the_first_differing_step_is_found(ab):
    a = _episode([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])
    assert ab.first_difference(a, _episode([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])) is None
    assert ab.first_difference(a, _episode([1.0, 2.0, 3.0], [0.0, 1e-9, 0.0])) == 1
    assert ab.first_difference(a, _episode([1.0, 2.0], [0.0, 0.0])) == 2  # one episode ended earlier
    rows = ab.compare({"p:s": a}, {"p:s": _episode([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], {"INFEASIBLE": 3})})
    assert rows["p:s"]["identical"] is False and rows["p:s"]["first_difference_step"] is None  # statuses differ


def test_a_tree_against_itself_is_identical_and_a_rerun_resumes(ab, tmp_path, capsys):
    out = tmp_path / "ab.json"
    argv = ["--baseline-src", str(SRC), "--json", str(out), "--runs", "idm:two-lane-d1.0", "--duration", "0.5"]
    assert ab.main(argv) == 0
    row = json.loads(out.read_text())["runs"]["idm:two-lane-d1.0"]
    assert row["identical"] and row["steps"] == 5
    current = tmp_path / "ab.current.json"
    recorded = current.read_text()
    assert ab.main(argv) == 0 and current.read_text() == recorded  # nothing rerun


@pytest.mark.parametrize("argv, message", [
    (["--baseline-src", "/nonexistent", "--json", "x.json"], "no driveopt package there"),
    (["--baseline-src", str(SRC), "--json", "x.json", "--runs", "bilevel"], "planner:scenario"),
    (["--baseline-src", str(SRC), "--json", "x.json", "--duration", "0"], "--duration must be positive"),
])
def test_bad_runs_are_refused(ab, capsys, argv, message):
    with pytest.raises(SystemExit) as stop:
        ab.main(argv)
    assert stop.value.code == 2 and message in capsys.readouterr().err
