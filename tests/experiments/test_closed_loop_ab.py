"""driveopt.experiments.closed_loop_ab and ``driveopt closed-loop-ab``: the same episodes under two source trees,
compared step by step."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import driveopt
from driveopt.cli import main
from driveopt.experiments.closed_loop_ab import compare, first_difference, split_run, this_tree

SRC = Path(driveopt.__file__).resolve().parents[1]  # the tree these tests import driveopt from


def _episode(speeds, lateral, statuses=None):
    return {"speeds": speeds, "lateral": lateral, "statuses": statuses or {"SUCCESS": len(speeds)}, "compile_seconds": 1.0}


def test_the_first_differing_step_is_found():
    a = _episode([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])
    assert first_difference(a, _episode([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])) is None
    assert first_difference(a, _episode([1.0, 2.0, 3.0], [0.0, 1e-9, 0.0])) == 1
    assert first_difference(a, _episode([1.0, 2.0], [0.0, 0.0])) == 2  # one episode ended earlier
    rows = compare({"p:s": a}, {"p:s": _episode([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], {"INFEASIBLE": 3})})
    assert rows["p:s"]["identical"] is False and rows["p:s"]["first_difference_step"] is None  # statuses differ
    assert split_run("idm:two-lane-d1.0") == ("idm", "two-lane-d1.0")
    for bad in ("bilevel", "a:b:c", ":two-lane-d1.0"):
        with pytest.raises(ValueError, match="planner:scenario"):
            split_run(bad)
    assert this_tree() == SRC


def test_a_tree_against_itself_is_identical_and_a_rerun_resumes(tmp_path, capsys):
    out = tmp_path / "ab.json"
    argv = ["closed-loop-ab", "--baseline-src", str(SRC), "--json", str(out), "--runs", "idm:two-lane-d1.0",
            "--duration", "0.5"]
    assert main(argv) == 0
    row = json.loads(out.read_text())["runs"]["idm:two-lane-d1.0"]
    assert row["identical"] and row["steps"] == 5
    assert "idm:two-lane-d1.0" in capsys.readouterr().out
    current = tmp_path / "ab.current.json"
    recorded = current.read_text()
    assert main(argv) == 0 and current.read_text() == recorded  # nothing rerun
    # a side whose record differs: the comparison says where, and the status is 1
    baseline = tmp_path / "ab.baseline.json"
    episodes = json.loads(baseline.read_text())
    episodes["idm:two-lane-d1.0"]["speeds"][2] += 1e-6
    baseline.write_text(json.dumps(episodes))
    assert main(argv) == 1
    row = json.loads(out.read_text())["runs"]["idm:two-lane-d1.0"]
    assert not row["identical"] and row["first_difference_step"] == 2


@pytest.mark.parametrize("argv, message", [
    (["--baseline-src", "/nonexistent", "--json", "x.json"], "no driveopt package there"),
    (["--baseline-src", str(SRC), "--json", "x.json", "--runs", "bilevel"], "planner:scenario"),
    (["--baseline-src", str(SRC), "--json", "x.json", "--runs", "nope:two-lane-d1.0"], "unknown planner 'nope'"),
    (["--baseline-src", str(SRC), "--json", "x.json", "--runs", "idm:nope"], "unknown scenario 'nope'"),
    (["--baseline-src", str(SRC), "--json", "x.txt"], "expected a file ending in .json"),
])
def test_bad_runs_are_one_line_errors(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(["closed-loop-ab", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("driveopt: error: ") and message in err and len(err.splitlines()) == 1
    assert not list(tmp_path.iterdir())  # refused before anything ran


def test_a_duration_that_is_not_positive_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["closed-loop-ab", "--baseline-src", str(SRC), "--json", "x.json", "--duration", "0"])
    assert stop.value.code == 2 and "--duration" in capsys.readouterr().err


def test_the_current_sides_overrides_reach_its_planners_alone_and_name_its_file(tmp_path, monkeypatch, capsys):
    from driveopt.experiments import closed_loop_ab, rollout

    class Episode:
        speeds, lateral, statuses, compile_seconds = [1.0], [0.0], {"SUCCESS": 1}, 0.0

    planned = []
    monkeypatch.setattr(rollout, "run_episode", lambda scenario, spec, seed, duration: planned.append(spec) or Episode())
    config = {"projection": {"max_iterations": 5}}
    files = closed_loop_ab.side_files(tmp_path / "ab.json", config)
    assert files["baseline"].name == "ab.baseline.json" and files["current"].name.startswith("ab.current-")
    assert closed_loop_ab.side_files(tmp_path / "ab.json", {"projection": {"max_iterations": 6}})["current"] != files["current"]
    closed_loop_ab.run_side(["bilevel:two-lane-d1.0"], 5, 0.5, files["current"], log=lambda line: None, config=config)
    closed_loop_ab.run_side(["bilevel:two-lane-d1.0"], 5, 0.5, files["baseline"], log=lambda line: None)
    assert [spec.config.projection.max_iterations for spec in planned] == [5, 12]
    (tmp_path / "c.json").write_text(json.dumps(config))
    assert main(["closed-loop-ab", "--baseline-src", str(SRC), "--json", str(tmp_path / "x.json"), "--runs",
                 "idm:two-lane-d1.0", "--current-config", str(tmp_path / "c.json")]) == 2
    assert "idm plans with no configuration" in capsys.readouterr().err
