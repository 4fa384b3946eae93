"""benchmarks/studies/stop_property.py: it plans both problem sets, counts both promises, catches a broken promise, and writes its
JSON at the end and on Ctrl-C."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from driveopt.config import PlannerConfig
from driveopt.planner import PlanStatus
from driveopt.scene import EgoState, Road, Scene
from driveopt.trajectory import Trajectory

from benchmarks.studies import stop_property

TINY = ["--samples", "16", "--iterations", "1", "--projection-iterations", "2"]


def test_it_plans_both_sets_and_counts_no_broken_fallback_promise(tmp_path):
    out = tmp_path / "s.json"
    assert stop_property.main(["--json", str(out), "--random", "3", "--realistic", "2", *TINY]) == 0
    report = json.loads(out.read_text())
    assert not report["interrupted"] and report["config"]["samples"] == 16
    for name, count in (("random", 3), ("realistic", 2)):
        tally = report["sets"][name]
        assert tally["planned"] == count == sum(tally["status"].values())
        assert tally["fallback_violations"]["problems"] == 0 and tally["success_against_travel"] <= tally["status"].get("SUCCESS", 0)


def test_ctrl_c_writes_what_was_planned(tmp_path, monkeypatch):
    real, calls = stop_property.plan, []

    def interrupted_plan(*args, **kwargs):
        calls.append(1)
        if len(calls) > 1:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(stop_property, "plan", interrupted_plan)
    out = tmp_path / "s.json"
    assert stop_property.main(["--json", str(out), "--random", "5", "--realistic", "5", *TINY]) == 130
    report = json.loads(out.read_text())
    assert report["interrupted"] and report["sets"]["random"]["planned"] == 1 and report["sets"]["realistic"]["planned"] == 0


def _stop(t, x, vx, speed, y=None):
    zeros = np.zeros_like(t)
    y = zeros + 4.0 if y is None else y
    return Trajectory(t, x, y, vx, zeros, zeros, zeros, speed, zeros, zeros, zeros)


def test_the_checks_catch_a_stop_that_drives_forwards_and_a_success_that_rolls_back():
    """A reversing ego (vx -15 m/s) whose fallback starts forwards at +15 m/s; a SUCCESS plan of a forward ego that
    rolls back 0.5 m at the end."""
    t = np.linspace(0.0, 15.0, 100)
    speed = np.maximum(15.0 - 3.0 * t, 0.0)
    ahead = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))])
    reversing = Scene(ego=EgoState(x=0.0, y=4.0, vx=-15.0), road=Road(num_lanes=3))
    forwards = SimpleNamespace(fallback=_stop(t, ahead, speed, speed), fallback_deceleration=3.0, status=PlanStatus.INFEASIBLE,
                               x_offset=0.0)
    assert {"start_velocity", "against_travel"} <= set(stop_property.fallback_violations(forwards, reversing))
    backwards = SimpleNamespace(**{**vars(forwards), "fallback": _stop(t, -ahead, -speed, speed)})
    assert stop_property.fallback_violations(backwards, reversing) == []
    assert stop_property.success_reversal(backwards, reversing) is None  # not a SUCCESS: no plan promise
    driving = Scene(ego=EgoState(x=0.0, y=4.0, vx=15.0), road=Road(num_lanes=3))
    rolled_back = ahead - np.where(t > 10.0, 0.5, 0.0)
    success = SimpleNamespace(status=PlanStatus.SUCCESS, x_offset=0.0, trajectory=_stop(t, rolled_back, speed, speed))
    limits = stop_property.reversal_limits(PlannerConfig())
    back, _ = stop_property.success_reversal(success, driving)
    assert back == pytest.approx(0.5) and stop_property.is_reversal(back, 0.0, limits)
    assert not stop_property.is_reversal(*stop_property.success_reversal(
        SimpleNamespace(**{**vars(success), "trajectory": _stop(t, ahead, speed, speed)}), driving), limits)
    assert stop_property.is_reversal(0.0, 0.06, limits) and not stop_property.is_reversal(0.0, 0.04, limits)


@pytest.mark.parametrize("argv, needle", [(["--random", "-1"], "--random"), (["--samples", "0"], "--samples")])
def test_bad_options_are_one_line_errors_and_write_nothing(tmp_path, capsys, argv, needle):
    out = tmp_path / "s.json"
    with pytest.raises(SystemExit) as exc:
        stop_property.main(["--json", str(out), *argv])
    assert exc.value.code == 2 and needle in capsys.readouterr().err
    assert not out.exists()
