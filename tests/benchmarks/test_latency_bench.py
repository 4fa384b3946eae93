"""benchmarks/perf/latency.py: planner-config overrides and obstacle counts are applied to every case, and bad ones refused."""

from __future__ import annotations

import json

import pytest

from benchmarks.perf import latency


def test_a_case_runs_with_the_overrides_and_is_recorded_with_them(tmp_path, monkeypatch):
    seen = []
    real = latency.plan

    def recording_plan(problem, config, **kwargs):
        seen.append(config)
        return real(problem, config, **kwargs)

    monkeypatch.setattr(latency, "plan", recording_plan)
    overrides = tmp_path / "c.json"
    overrides.write_text(json.dumps({"projection": {"course_max": 0.0}}))
    out = tmp_path / "lat.json"
    assert latency.main(["--json", str(out), "--calls", "2", "--batches", "50", "--config", str(overrides),
                         "--schedules", "1x2"]) == 0
    report = json.loads(out.read_text())
    assert report["config"] == {"projection": {"course_max": 0.0}}
    assert [r["case"] for r in report["results"]] == ["50x1x2"]
    assert sum(report["results"][0]["statuses"].values()) == 2  # what each timed call returned
    assert report["results"][0]["median_residual"] >= 0.0
    assert seen and all(c.projection.course_max == 0.0 and c.sampler.num_samples == 50 for c in seen)


@pytest.mark.parametrize("content, message", [
    ('{"projection": {"course_max": 2.0}}', "course_max"),
    ('{"projection": {"no_such_key": 1}}', "no_such_key"),
    ("not json", "cannot read config"),
])
def test_bad_overrides_are_refused_in_one_line(tmp_path, capsys, content, message):
    overrides = tmp_path / "c.json"
    overrides.write_text(content)
    assert latency.main(["--json", str(tmp_path / "lat.json"), "--config", str(overrides)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not (tmp_path / "lat.json").exists()


def test_resuming_with_other_overrides_is_refused(tmp_path, capsys):
    out = tmp_path / "lat.json"
    out.write_text(json.dumps({"machine": {}, "config": {"projection": {"course_max": 0.0}}, "results": []}))
    assert latency.main(["--json", str(out), "--resume"]) == 2
    assert "resume with the same --config" in capsys.readouterr().err
    assert json.loads(out.read_text())["results"] == []


def test_fewer_obstacles_plan_against_that_many_and_are_named(tmp_path, monkeypatch):
    counts = []
    real = latency.plan

    def recording_plan(problem, config, **kwargs):
        counts.append(problem.obstacle_x.shape[0])
        return real(problem, config, **kwargs)

    monkeypatch.setattr(latency, "plan", recording_plan)
    monkeypatch.setattr(latency, "SCHEDULES", ((1, 2),))
    out = tmp_path / "lat.json"
    assert latency.main(["--json", str(out), "--calls", "1", "--batches", "50", "--obstacles", "10", "3"]) == 0
    results = json.loads(out.read_text())["results"]
    assert [(r["case"], r["obstacles"]) for r in results] == [("50x1x2", 10), ("50x1x2-3obstacles", 3)]
    assert counts == [10, 10, 3, 3]
    with pytest.raises(SystemExit) as exc:
        latency.main(["--json", str(tmp_path / "other.json"), "--obstacles", "0"])
    assert exc.value.code == 2


@pytest.mark.parametrize("schedule", ["5", "0x20", "5x", "ax2"])
def test_a_malformed_schedule_is_refused(schedule, capsys):
    with pytest.raises(SystemExit) as stop:
        latency.main(["--json", "x.json", "--schedules", schedule])
    assert stop.value.code == 2 and "IxP" in capsys.readouterr().err
