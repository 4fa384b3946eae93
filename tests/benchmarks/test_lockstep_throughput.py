"""benchmarks/perf/lockstep_throughput.py: the bench command line of each setting, and its checks (the timed runs
themselves are `driveopt bench`, tested in tests/experiments/test_lockstep.py)."""

import argparse
from pathlib import Path

import pytest

from benchmarks.perf import lockstep_throughput


def test_each_setting_is_one_bench_command():
    args = argparse.Namespace(scenario="four-lane-d3.0", planner="bilevel", seed=42, samples=250)
    argv = lockstep_throughput.bench_argv(Path("OUT"), args, 16, 5.0, {"lockstep": 4})
    assert argv[1:4] == ["-m", "driveopt.cli", "bench"] and argv[-2:] == ["--lockstep", "4"]
    assert argv[argv.index("--episodes") + 1] == "16" and argv[argv.index("--duration") + 1] == "5.0"
    assert lockstep_throughput.bench_argv(Path("OUT"), args, 2, 0.3, {"workers": 2})[-2:] == ["--workers", "2"]
    both = lockstep_throughput.bench_argv(Path("OUT"), args, 16, 5.0, {"lockstep": 2, "workers": 2})
    assert both[-4:] == ["--lockstep", "2", "--workers", "2"]


@pytest.mark.parametrize("argv", [["--lockstep", "0"], ["--workers", "0"], ["--duration", "0"], ["--episodes", "0"],
                                  ["--lockstep-workers", "0"]])
def test_bad_sizes_are_refused(argv, capsys, tmp_path):
    with pytest.raises(SystemExit) as exit_:
        lockstep_throughput.main(["--json", str(tmp_path / "x.json"), *argv])
    assert exit_.value.code == 2 and "must be >= 1" in capsys.readouterr().err and not (tmp_path / "x.json").exists()


def _outcome(collided=False, steps=50, speed=8.0, statuses=None):
    return {"collided": collided, "steps": steps, "statuses": statuses or {"SUCCESS": steps}, "mean_speed": speed}


def test_agreement_counts_the_shared_episodes_that_match():
    reference = {"outcomes": {"42/0": _outcome(), "42/1": _outcome(True, 20), "42/2": _outcome()}}
    run = {"outcomes": {"42/0": _outcome(speed=8.25), "42/1": _outcome(True, 21, statuses={"SUCCESS": 20, "INFEASIBLE": 1})}}
    assert lockstep_throughput.agreement(run, reference) == {
        "episodes": 2, "same_collided": 2, "same_steps": 1, "same_statuses": 1, "max_mean_speed_difference": 0.25}


def test_a_rerun_keeps_the_settings_measured_and_refuses_other_parameters(tmp_path, monkeypatch, capsys):
    ran = []

    def fake_run(args, setting, folder):
        ran.append(setting)
        return {**setting, "episodes": 1, "wall_s": 1.0, "episodes_per_hour": 3600.0, "plan_ms_median": 1.0,
                "outcomes": {"42/0": _outcome()}}

    monkeypatch.setattr(lockstep_throughput, "run_setting", fake_run)
    out = str(tmp_path / "x.json")
    lockstep_throughput.main(["--json", out, "--lockstep", "1", "2", "--workers", "2"])
    lockstep_throughput.main(["--json", out, "--lockstep", "1", "2", "4", "--workers", "2"])
    assert ran == [{"workers": 2}, {"lockstep": 1}, {"lockstep": 2}, {"lockstep": 4}], "each setting once"
    import json

    results = json.loads((tmp_path / "x.json").read_text())["results"]
    assert [r.get("agreement", {}).get("same_collided") for r in results] == [None, 1, 1, 1]
    with pytest.raises(SystemExit):
        lockstep_throughput.main(["--json", out, "--samples", "1000"])
    assert "other parameters" in capsys.readouterr().err
