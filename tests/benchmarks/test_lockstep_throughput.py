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


@pytest.mark.parametrize("argv", [["--lockstep", "0"], ["--workers", "0"], ["--duration", "0"], ["--episodes", "0"]])
def test_bad_sizes_are_refused(argv, capsys, tmp_path):
    with pytest.raises(SystemExit) as exit_:
        lockstep_throughput.main(["--json", str(tmp_path / "x.json"), *argv])
    assert exit_.value.code == 2 and "must be >= 1" in capsys.readouterr().err and not (tmp_path / "x.json").exists()
