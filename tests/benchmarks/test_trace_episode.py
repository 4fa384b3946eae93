"""benchmarks/trace_episode.py: one bench episode replayed step by step, with one-line errors for bad options."""

from __future__ import annotations

import json

import benchmark_scripts
import pytest

from driveopt.errors import DriveoptError
from driveopt.experiments.rollout import run_episode
from driveopt.experiments.store import JobKey
from driveopt.registry import get_planner


@pytest.fixture(scope="module")
def trace_episode():
    return benchmark_scripts.load("trace_episode")


def test_the_trace_replays_the_bench_episode_step_by_step(trace_episode, tmp_path, capsys):
    summary, rows = trace_episode.trace("two-lane-d1.0", "grid", 3, samples=40, duration=0.5)
    # The bench's traffic for that episode: the same speeds as run_episode with the bench's seed.
    bench = run_episode("two-lane-d1.0", get_planner("grid").with_samples(40), JobKey("two-lane-d1.0", "grid", 42, 3).env_seed,
                        duration=0.5)
    assert summary["env_seed"] == 42 * 100_003 + 3 and len(rows) == 5
    assert [row["speed"] for row in rows[1:]] == [round(v, 2) for v in bench.speeds[:-1]]
    assert all(row["status"] in ("SUCCESS", "INFEASIBLE") and len(row["setpoints"]) == 8 and len(row["plan_y"]) == 4
               for row in rows)
    assert [row["t"] for row in rows] == sorted(row["t"] for row in rows)
    out = tmp_path / "trace.json"
    assert trace_episode.main(["--scenario", "two-lane-d1.0", "--planner", "idm", "--episode", "3", "--duration", "0.5",
                               "--last", "0.2", "--json", str(out)]) == 0
    written = json.loads(out.read_text())
    assert len(written["steps"]) == 5 and "status" not in written["steps"][0]  # idm plans nothing
    assert json.loads(capsys.readouterr().out.splitlines()[0])["planner"] == "idm"


def test_bad_options_are_one_line_errors(trace_episode, tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"cost": {"nope": 1.0}}))
    assert trace_episode.main(["--scenario", "nope", "--planner", "grid", "--episode", "0"]) == 2
    assert trace_episode.main(["--scenario", "two-lane-d1.0", "--planner", "grid", "--episode", "0", "--config", str(bad)]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 2 and "unknown scenario 'nope'" in errors[0] and "nope" in errors[1]
    with pytest.raises(DriveoptError, match="applies to optimisers"):
        trace_episode.trace("two-lane-d1.0", "idm", 0, overrides={"cost": {"consistency": 0.0}}, duration=0.2)
    with pytest.raises(SystemExit):
        trace_episode.main(["--scenario", "two-lane-d1.0", "--planner", "grid", "--episode", "-1"])
    # weights the bench would refuse are refused here too, before any episode runs
    assert trace_episode.main(["--scenario", "two-lane-d1.0", "--planner", "vqvae", "--episode", "0",
                               "--weights", str(tmp_path / "missing.ckpt")]) == 2
    assert "missing.ckpt does not exist" in capsys.readouterr().err
