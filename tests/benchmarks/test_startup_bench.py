"""benchmarks/perf/startup.py: light commands timed in fresh processes; a first and a second plan with one cache folder, the
second loading what the first compiled."""

from __future__ import annotations

import json

import pytest

from benchmarks.perf import startup


def test_a_light_command_is_timed_in_fresh_processes():
    record = startup.time_light("help", ["--help"], 2)
    assert record["argv"] == ["--help"] and len(record["runs"]) == 2 and record["median_s"] > 0 < record["cpu_median_s"]
    assert len(record["load_before"]) == 3 and len(record["load_after"]) == 3


@pytest.mark.slow  # two plans, one compiling (tests/cli/test_compilation_cache.py checks the cache in the default run)
def test_light_commands_and_a_plan_pair_are_recorded(tmp_path, monkeypatch):
    monkeypatch.setattr(startup, "LIGHT", {"help": ["--help"], "planners": ["planners"]})
    out = tmp_path / "startup.json"
    assert startup.main(["--json", str(out), "--runs", "2", "--plan-runs", "1", "--plan-args", "--samples", "10",
                         "--iterations", "2", "--projection-iterations", "2", "--repeats", "1"]) == 0
    report = json.loads(out.read_text())
    assert len(report["load_before"]) == 3 and report["machine"]["cpus"] >= 1
    assert set(report["commands"]) == {"help", "planners"}
    assert all(len(c["runs"]) == 2 and c["median_s"] > 0 for c in report["commands"].values())
    plan = report["plan"]
    assert plan["cache_entries"] == [["jit_solve"]]  # the first plan wrote the compiled planner
    first, second = plan["plan_first"][0], plan["plan_second"][0]
    assert first["solve_s"] > 0 and second["solve_s"] > 0
    assert second["first_call_s"] < first["first_call_s"] and second["cpu_s"] < first["cpu_s"]  # loading, not compiling
    assert plan["plan_second_median"]["start_to_plan_s"] == pytest.approx(second["wall_s"] - second["solve_s"])


def test_plan_args_need_repeats(capsys):
    with pytest.raises(SystemExit):
        startup.main(["--plan-args", "--samples", "10"])
    assert "--repeats" in capsys.readouterr().err
