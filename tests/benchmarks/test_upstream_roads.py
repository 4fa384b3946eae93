"""benchmarks/studies/upstream_roads.py: planner-config overrides, the time gap and the tracking within the period reach the
controller and are recorded; the table reads the summary."""

from __future__ import annotations

import json

import numpy as np
import pytest

from driveopt.config import ProjectionConfig
from driveopt.sim.route_goal import RouteChange

from benchmarks.studies import upstream_roads


@pytest.mark.slow  # compiles a planner and drives highway-v0 for two decisions
def test_a_config_drives_the_episode_and_is_recorded_with_it(tmp_path):
    config = tmp_path / "c.json"
    config.write_text(json.dumps({"projection": {"max_iterations": 3}}))
    out = tmp_path / "out"
    assert upstream_roads.main(["--out", str(out), "--envs", "highway-v0", "--planners", "bilevel", "--episodes", "1",
                                "--samples", "8", "--duration", "2", "--config", str(config), "--time-gap", "0.3"]) == 0
    (record,) = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert "refused" not in record and record["steps"] >= 1
    digest = record["settings"].pop("planner_config")  # the configuration the overrides make, defaults included
    assert record["settings"] == {"samples": 8, "duration": 2.0, "traffic": "upstream's constants",
                                  "config": {"projection": {"max_iterations": 3}}, "time_gap": 0.3,
                                  "tracked_within_period": True, "plan_frequency": 5.0}
    from driveopt.registry import get_optimiser

    assert digest == get_optimiser("bilevel").with_samples(8).with_overrides(projection={"max_iterations": 3}).config_digest()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["settings"]["config"] == {"projection": {"max_iterations": 3}} and summary["settings"]["time_gap"] == 0.3
    assert (out / "table.md").read_text().startswith("| upstream env | `bilevel`, 8 samples")


@pytest.mark.parametrize("env_id, hz, rate", [
    ("intersection-v0", 5.0, 5.0), ("intersection-v0", 4.0, None),  # 1 Hz, 15 simulation steps a period
    ("highway-fast-v0", 5.0, 5.0), ("highway-fast-v0", 3.0, None),  # 1 Hz, 5 steps
    ("racetrack-v0", 5.0, None), ("racetrack-v0", 15.0, 15.0),  # 5 Hz, 3 steps: 5 Hz is its own rate
    ("intersection-v0", None, 5.0), ("racetrack-v0", None, None),  # the controller's default, 5 Hz
    ("intersection-v0", 1.0, None),  # once per policy step
])
def test_plan_frequency_applies_where_it_replans_within_the_envs_period(env_id, hz, rate):
    assert upstream_roads.plan_rate(env_id, hz) == rate


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


def test_the_preview_ab_refuses_an_unknown_field_a_bad_value_or_a_missing_separator():
    from benchmarks.studies import preview_ab

    with pytest.raises(SystemExit, match="unexpected keyword argument 'bogus'"):
        preview_ab.main(["bogus=1", "--", "--out", "x"])
    with pytest.raises(SystemExit, match="unexpected keyword argument 'bogus'"):
        preview_ab.main(["route_change.bogus=1", "--", "--out", "x"])
    with pytest.raises(SystemExit, match="RouteChange.comfortable_lane_time must be a number"):
        preview_ab.main(["route_change.comfortable_lane_time=0", "--", "--out", "x"])
    with pytest.raises(SystemExit, match="RoadPreview.speed_distance must be a number"):
        preview_ab.main(["speed_distance=-1", "--", "--out", "x"])
    with pytest.raises(SystemExit, match="could not convert"):
        preview_ab.main(["speed_distance=far", "--", "--out", "x"])
    with pytest.raises(SystemExit, match="usage"):
        preview_ab.main(["speed_distance=0"])
    with pytest.raises(SystemExit, match="curvature_per_node must be True or False"):
        preview_ab.main(["curvature_per_node=1", "--", "--out", "x"])
    assert preview_ab.preview_fields(["speed_distance=0", "curvature_per_node=True", "route_change.comfortable_lane_time=2"]) == {
        "speed_distance": 0.0, "curvature_per_node": True, "route_change": RouteChange(comfortable_lane_time=2.0)}


def test_the_curve_speed_ceiling_drives_each_road_at_its_limit_or_its_curve_speed():
    """100 m straight at the 10 m/s limit (10 s) and 50 m of radius 25 m: at 4 m/s^2 the curve allows 10 m/s (5 s),
    at 1 m/s^2 5 m/s (10 s): 150 / 15 and 150 / 20 m/s."""
    from benchmarks.studies import curve_speed_ceiling

    roads = [{"length": 100.0, "curvature": 0.0, "speed_limit": 10.0},
             {"length": 50.0, "curvature": 1.0 / 25.0, "speed_limit": 10.0}]
    assert curve_speed_ceiling.ceiling(roads, 4.0) == pytest.approx(10.0)
    assert curve_speed_ceiling.ceiling(roads, 1.0) == pytest.approx(7.5)
    with pytest.raises(SystemExit):
        curve_speed_ceiling.main(["--out", "x.json", "--bounds", "0"])


def test_the_arrival_ceiling_accelerates_brakes_for_curves_and_reads_each_routed_envs_route(tmp_path):
    """Straight 100 m from 0 m/s at 2 m/s^2, capped at 10 m/s: 5 s to the cap (25 m), 7.5 s for the other 75 m. A curve
    of radius 25 m at the end, at 1 m/s^2 (5 m/s): the car brakes from 10 m/s in time (18.75 m before it)."""
    from benchmarks.studies import arrival_ceiling

    step = arrival_ceiling.STEP
    straight = np.zeros(int(round(100.0 / step)) + 1)
    assert arrival_ceiling.fastest_time(straight, 0.0, 4.0, 2.0, 10.0) == pytest.approx(12.5, rel=1e-3)
    curve = np.concatenate([straight, np.full(int(round(50.0 / step)), 1.0 / 25.0)])
    # accelerate to 10 (25 m, 5 s), cruise, brake 10 -> 5 (18.75 m, 2.5 s), then 50 m at 5 m/s (10 s)
    assert arrival_ceiling.fastest_time(curve, 0.0, 1.0, 2.0, 10.0) == pytest.approx(5.0 + 56.25 / 10.0 + 2.5 + 10.0, rel=1e-2)
    out = tmp_path / "ceiling.json"
    assert arrival_ceiling.main(["--out", str(out), "--envs", "intersection-v0", "--episodes", "2", "--bounds", "4"]) == 0
    result = json.loads(out.read_text())["results"]["intersection-v0"]
    assert result["duration_s"] == 13.0 and len(result["episodes"]) == 2
    for episode in result["episodes"]:
        assert episode["route"][0][0] == "o0" and 30.0 < episode["distance_m"] < 80.0
        assert 0.0 < episode["earliest_arrival_s"]["4"] < 13.0
    with pytest.raises(SystemExit):
        arrival_ceiling.main(["--out", str(out), "--bounds", "0"])


def test_the_curve_turn_study_records_each_step_of_a_racetrack_episode_and_refuses_bad_arguments(tmp_path):
    from benchmarks.studies import curve_lateral_acceleration as study

    out = tmp_path / "turns.json"
    assert study.main(["--out", str(out), "--envs", "racetrack-v0", "--episodes", "1", "--duration", "0.4"]) == 0
    (record,) = json.loads(out.read_text())["episodes"]
    assert record["env"] == "racetrack-v0" and record["steps"] == 2 and record["bound"] == ProjectionConfig.centripetal_max
    assert record["max_turn"] >= 0.0 and 0 <= record["steps_above_bound"] <= 2
    assert 0 <= record["steps_over_speed_limit"] <= 2
    assert (record["steps_over_speed_limit"] > 0) == (record["max_over_speed_limit"] > study.OVER_LIMIT)
    with pytest.raises(SystemExit):
        study.main(["--out", str(out), "--duration", "0"])


def test_a_routed_row_drives_its_env_along_the_given_route_and_counts_its_end(tmp_path):
    row = "exit-v0, straight on"
    assert upstream_roads.ROUTED_ROWS[row] == ("exit-v0", ("0", "1", "2", "3"))
    record = upstream_roads.run_episode(row, "idm", 0, 250, 2.0)
    assert record["env"] == row and record["setup"] == upstream_roads.ROUTE_REACHED
    assert record["steps"] == 2 and record["arrived"] is False  # 2 s in: not yet on ("2", "3")
    results = {row: {"idm": {"episodes": 1, "collisions": 0, "off_road_episodes": 0, "refused": 0, "arrived": 0,
                             "mean_speed": 20.0, "plan_ms_median": None}},
               "exit-v0": {"idm": {"episodes": 1, "collisions": 0, "off_road_episodes": 0, "refused": 0, "arrived": 1,
                                   "mean_speed": 20.0, "plan_ms_median": None}}}
    lines = upstream_roads.table(results, ["idm"], 250).splitlines()
    assert lines[2].startswith("| `exit-v0` |") and lines[3].startswith(f"| `{row}` |")  # the env's rows first
    with pytest.raises(SystemExit):
        upstream_roads.main(["--out", str(tmp_path), "--envs", "exit-v0, sideways"])


def test_a_record_planned_before_a_default_changed_is_driven_again_and_left_out(tmp_path, monkeypatch):
    """Each optimiser record names its configuration's digest, defaults included: a record of another configuration
    (a default changed since) is not this run's; one written before the digest was recorded is matched without it."""
    driven = []

    def episode(env_id, planner, seed, *args):
        driven.append(seed)
        return {"env": env_id, "planner": planner, "seed": seed, "collided": False, "off_road": False, "arrived": None,
                "mean_speed": 10.0 + seed, "time": 2.0, "steps": 2, "statuses": {}, "plan_ms_median": 1.0}

    monkeypatch.setattr(upstream_roads, "run_episode", episode)
    out = tmp_path / "out"
    argv = ["--out", str(out), "--envs", "highway-v0", "--planners", "bilevel", "--episodes", "3", "--duration", "2"]
    assert upstream_roads.main(argv) == 0 and driven == [0, 1, 2]
    records = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert all(len(r["settings"]["planner_config"]) == 16 for r in records)
    older = {k: v for k, v in records[0]["settings"].items() if k != "planner_config"}
    records[0]["settings"] = older  # written before configurations were named: still this run's
    records[1]["settings"] = {**records[1]["settings"], "planner_config": "0123456789abcdef"}  # another default
    (out / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    driven.clear()
    assert upstream_roads.main(argv) == 0 and driven == [1]
    summary = json.loads((out / "summary.json").read_text())["results"]["highway-v0"]["bilevel"]
    assert summary["episodes"] == 3 and summary["mean_speed"] == pytest.approx(11.0)  # seeds 0, 1 (again) and 2
