"""driveopt.experiments.trace_episode and ``driveopt trace-episode``: one bench episode replayed step by step, with
one-line errors for bad options."""

from __future__ import annotations

import json

import pytest

from driveopt.cli import main
from driveopt.errors import DriveoptError
from driveopt.experiments.rollout import run_episode
from driveopt.experiments.store import JobKey
from driveopt.experiments.trace_episode import step_line, trace
from driveopt.registry import get_planner


def test_the_trace_replays_the_bench_episode_step_by_step(tmp_path, capsys):
    summary, rows = trace("two-lane-d1.0", "grid", 3, samples=40, duration=0.5)
    # The bench's traffic for that episode: the same speeds as run_episode with the bench's seed.
    bench = run_episode("two-lane-d1.0", get_planner("grid").with_samples(40), JobKey("two-lane-d1.0", "grid", 42, 3).env_seed,
                        duration=0.5)
    assert summary["env_seed"] == 42 * 100_003 + 3 and len(rows) == 5
    assert [row["speed"] for row in rows[1:]] == [round(v, 2) for v in bench.speeds[:-1]]
    assert all(row["status"] in ("SUCCESS", "INFEASIBLE") and len(row["setpoints"]) == 8 and len(row["plan_y"]) == 4
               for row in rows)
    assert [row["t"] for row in rows] == sorted(row["t"] for row in rows)
    assert step_line(rows[0]).startswith(f"t={rows[0]['t']:5.1f}") and " res=" in step_line(rows[0])
    out = tmp_path / "trace.json"
    assert main(["trace-episode", "--scenario", "two-lane-d1.0", "--planner", "idm", "--episode", "3", "--duration", "0.5",
                 "--last", "0.2", "--json", str(out)]) == 0
    written = json.loads(out.read_text())
    assert len(written["steps"]) == 5 and "status" not in written["steps"][0]  # idm plans nothing
    printed = capsys.readouterr().out.splitlines()
    assert json.loads(printed[0])["planner"] == "idm"
    last_t = written["steps"][-1]["t"]
    shown = [row for row in written["steps"] if row["t"] >= last_t - 0.2]  # --last: only the episode's end is printed
    assert printed[1:-1] == [step_line(row) for row in shown] and printed[-1] == f"wrote {out}"


def test_bad_options_are_one_line_errors(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"cost": {"nope": 1.0}}))
    assert main(["trace-episode", "--scenario", "nope", "--planner", "grid", "--episode", "0"]) == 2
    assert main(["trace-episode", "--scenario", "two-lane-d1.0", "--planner", "grid", "--episode", "0", "--config", str(bad)]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 2 and all(line.startswith("driveopt: error: ") for line in errors)
    assert "unknown scenario 'nope'" in errors[0] and "nope" in errors[1]
    with pytest.raises(DriveoptError, match="applies to optimisers"):
        trace("two-lane-d1.0", "idm", 0, overrides={"cost": {"consistency": 0.0}}, duration=0.2)
    for option, value in (("--episode", "-1"), ("--last", "0"), ("--samples", "0"), ("--duration", "-1")):
        argv = ["trace-episode", "--scenario", "two-lane-d1.0", "--planner", "grid", "--episode", "0", option, value]
        with pytest.raises(SystemExit) as stop:
            main(argv)
        assert stop.value.code == 2
        err = capsys.readouterr().err
        assert err.startswith("driveopt: error: ") and option in err and len(err.splitlines()) == 1
    # weights the bench would refuse are refused here too, before any episode runs
    assert main(["trace-episode", "--scenario", "two-lane-d1.0", "--planner", "vqvae", "--episode", "0",
                 "--weights", str(tmp_path / "missing.ckpt")]) == 2
    assert "missing.ckpt does not exist" in capsys.readouterr().err


def test_a_seed_whose_traffic_seed_overflows_is_a_one_line_error(capsys):
    """--seed 42949 passes the 32-bit seed type, but its traffic seed (seed x 100003 + episode) does not fit: refused
    before the episode, naming the range, not an OverflowError from the simulator."""
    assert main(["trace-episode", "--scenario", "two-lane-d1.0", "--planner", "idm", "--episode", "0", "--seed", "42949"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("driveopt: error: seed 42949 is out of range: seeds are integers from 0 to 42948")
    assert err.count("\n") == 1
