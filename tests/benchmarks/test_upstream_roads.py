"""benchmarks/studies/upstream_roads.py: planner-config overrides and the tracking within the period reach the
controller and are recorded; the table reads the summary."""

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
    assert record["settings"] == {"samples": 8, "duration": 2.0, "traffic": "upstream's constants",
                                  "config": {"projection": {"max_iterations": 3}}, "tracked_within_period": True}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["settings"]["config"] == {"projection": {"max_iterations": 3}}
    assert (out / "table.md").read_text().startswith("| upstream env | `bilevel`, 8 samples")


def test_the_table_shows_each_planners_counts_and_says_what_was_refused():
    results = {"roundabout-v0": {"bilevel": {"episodes": 20, "collisions": 2, "off_road_episodes": 1, "refused": 1,
                                             "arrived": 12, "mean_speed": 8.4795, "plan_ms_median": 43.2},
                                 "idm": {"episodes": 20, "collisions": 7, "off_road_episodes": 6, "refused": 0,
                                         "arrived": 0, "mean_speed": 17.3, "plan_ms_median": None}},
               "parking-v0": {"bilevel": {"episodes": 20, "collisions": 0, "off_road_episodes": 0, "refused": 20,
                                          "arrived": None, "mean_speed": None, "plan_ms_median": None}}}
    lines = upstream_roads.table(results, ["bilevel", "idm"], 250).splitlines()
    assert lines[0].startswith("| upstream env | `bilevel`, 250 samples") and len(lines) == 4
    assert lines[2] == "| `roundabout-v0` | 2, 1 / 20, 1 refused, 12 arrived, 8.48, 43 ms | 7, 6 / 20, 0 arrived, 17.30 |"
    assert lines[3] == "| `parking-v0` | refused (20 / 20) | not run |"


def test_the_pace_ab_refuses_an_unknown_field_or_a_missing_separator():
    from benchmarks.studies import route_change_ab

    with pytest.raises(SystemExit, match="unexpected keyword argument 'bogus'"):
        route_change_ab.main(["bogus=1", "--", "--out", "x"])
    with pytest.raises(SystemExit, match="must be a number"):
        route_change_ab.main(["comfortable_lane_time=0", "--", "--out", "x"])
    with pytest.raises(SystemExit, match="usage"):
        route_change_ab.main(["comfortable_lane_time=2"])
