"""benchmarks/perf/row_sharing_ab.py: both row sharings plan every state with the same key, the record resumes, and runs
that cannot compare anything are refused."""

from __future__ import annotations

import json

import pytest

from driveopt.problem import build_problem
from driveopt.scene import load_scene

from benchmarks.perf import row_sharing_ab as ab


@pytest.mark.slow  # two planner graphs compiled for one benchmark script: benchmark-sized
def test_both_sharings_plan_each_state_and_a_rerun_resumes(tmp_path, monkeypatch):
    spec = ab.get_optimiser("vqvae").with_samples(24)
    problem = build_problem(load_scene("dense-snapshot"), spec.config.basis)
    monkeypatch.setattr(ab, "states", lambda *args: [problem, problem])  # two states, without driving an episode
    calls = []
    real = ab.planner.plan

    def recording_plan(problem, config, **kwargs):
        calls.append((int(kwargs["key"][1]), type(kwargs["method"].row_sharing).__name__))
        return real(problem, config, **kwargs)

    monkeypatch.setattr(ab.planner, "plan", recording_plan)
    out = tmp_path / "ab.json"
    arguments = ["--json", str(out), "--planner", "vqvae", "--samples", "24", "--episodes", "1"]
    assert ab.main(arguments) == 0
    report = json.loads(out.read_text())
    assert [sorted(calls[2:4]), sorted(calls[4:])] == [[(0, "DistinctRows"), (0, "EveryRow")],
                                                       [(1, "DistinctRows"), (1, "EveryRow")]]  # after two compiling calls
    for state in report["states"]:
        assert state["same_pick"] and state["status"][0] == state["status"][1]
        assert 1 <= state["distinct_rows"] <= state["rows"] == 24 + 2  # the samples and the two stops (no previous plan)
        assert min(state["plan_ms"]) > 0
    assert report["summary"]["states"] == report["summary"]["same_pick"] == 2
    calls.clear()
    assert ab.main(arguments) == 0  # nothing left to do but the compiling calls
    assert len(calls) == 2 and len(json.loads(out.read_text())["states"]) == 2
    with pytest.raises(SystemExit):  # the record holds other arguments
        ab.main([*arguments[:-1], "2"])


def test_a_planner_that_projects_every_row_is_refused(tmp_path):
    with pytest.raises(SystemExit):
        ab.main(["--json", str(tmp_path / "ab.json"), "--planner", "bilevel"])
    assert not (tmp_path / "ab.json").exists()
