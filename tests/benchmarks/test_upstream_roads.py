"""benchmarks/studies/upstream_roads.py: planner-config overrides reach the controller and are recorded."""

from __future__ import annotations

import json

import pytest

from benchmarks.studies import upstream_roads


@pytest.mark.slow  # compiles a planner and drives highway-v0 for two decisions
def test_a_config_drives_the_episode_and_is_recorded_with_it(tmp_path):
    config = tmp_path / "c.json"
    config.write_text(json.dumps({"projection": {"max_iterations": 3}}))
    out = tmp_path / "out"
    assert upstream_roads.main(["--out", str(out), "--envs", "highway-v0", "--planners", "bilevel", "--episodes", "1",
                                "--samples", "8", "--duration", "2", "--config", str(config)]) == 0
    (record,) = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert "refused" not in record and record["steps"] >= 1
    assert record["settings"] == {"samples": 8, "duration": 2.0, "config": {"projection": {"max_iterations": 3}}}
    assert json.loads((out / "summary.json").read_text())["settings"]["config"] == {"projection": {"max_iterations": 3}}
