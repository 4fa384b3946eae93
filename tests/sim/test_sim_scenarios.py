"""Scenario registry: names, fields, overrides and their error messages."""

from __future__ import annotations

import dataclasses
import json
import math
import os

import pytest

from driveopt.sim.scenarios import (
    DENSITIES,
    Scenario,
    ScenarioError,
    apply_overrides,
    get_scenario,
    list_scenarios,
    load_overrides,
    resolve_scenario,
)


def test_registry_names_follow_the_scheme():
    names = list_scenarios()
    expected = {
        f"{word}-lane-d{d:.1f}{suffix}" for word in ("two", "four") for d in DENSITIES for suffix in ("", "-slow")
    } | {f"{word}-lane-d{d:.1f}" for word in ("three", "five") for d in DENSITIES} | {"two-way", "merge"}
    expected |= {f"p2-four-lane-d{d:.1f}{suffix}" for d in DENSITIES for suffix in ("", "-slow")}
    assert set(names) == expected
    assert len(names) == len(expected) == 42


@pytest.mark.parametrize("name", ["four-lane-d3.0", "two-lane-d2.5", "two-lane-d1.0-slow", "four-lane-d1.5-slow",
                                  "three-lane-d2.0", "five-lane-d3.0"])
def test_highway_scenarios_carry_their_name(name):
    s = get_scenario(name)
    assert s.name == name and s.road == "highway"
    assert s.lanes == {"two": 2, "three": 3, "four": 4, "five": 5}[name.split("-")[0]]
    assert s.density == float(name.split("-d")[1][:3])
    assert s.speed_limit == (7.0 if name.endswith("-slow") else 15.0)
    assert s.target_speed_fraction == (0.7, 0.8)
    assert s.duration == 50.0 and s.v_des == 20.0 and s.policy_frequency == 10
    assert s.simulation_frequency % s.policy_frequency == 0


@pytest.mark.parametrize("name, density, limit", [("p2-four-lane-d3.0", 3.0, 15.0), ("p2-four-lane-d1.5-slow", 1.5, 7.0)])
def test_p2_traffic_variants_draw_target_speeds_between_zero_and_the_limit(name, density, limit):
    s = get_scenario(name)
    assert (s.road, s.lanes, s.density, s.speed_limit) == ("highway", 4, density, limit)
    assert s.target_speed_fraction == (0.0, 1.0) and s.target_speed_range == (0.0, limit)
    # the same road and traffic density as driveopt's P1 scenario of that name: only the target speeds differ
    p1 = get_scenario(name.removeprefix("p2-"))
    assert dataclasses.replace(s, name=p1.name, target_speed_fraction=p1.target_speed_fraction, description=p1.description) == p1
    assert resolve_scenario(p1.name, overrides={"target_speed_fraction": [0, 1]}).target_speed_range == (0.0, limit)


def test_two_way_and_merge_use_their_upstream_roads():
    assert get_scenario("two-way").road == "two-way"
    assert get_scenario("merge").road == "merge"
    assert get_scenario("two-way").lanes == get_scenario("merge").lanes == 2


def test_unknown_scenario_lists_valid_names():
    with pytest.raises(ValueError) as info:
        get_scenario("four-lane-d3.5")
    message = str(info.value)
    assert "four-lane-d3.5" in message
    for name in list_scenarios():
        assert name in message
    assert "did you mean" in message


def test_scenario_is_frozen_and_hashable():
    s = get_scenario("two-lane-d1.0")
    with pytest.raises(AttributeError):
        s.density = 2.0  # type: ignore[misc]
    assert hash(s) == hash(get_scenario("two-lane-d1.0"))


def test_overrides_are_coerced_and_validated():
    s = apply_overrides(get_scenario("two-lane-d1.0"), {"density": 2, "target_speed_fraction": [0.5, 0.9], "lanes": 3})
    assert s.density == 2.0 and isinstance(s.density, float)
    assert s.target_speed_fraction == (0.5, 0.9)
    assert s.lanes == 3
    assert s.target_speed_range == pytest.approx((7.5, 13.5))
    assert s.replace(duration=10) == apply_overrides(s, {"duration": 10.0})


@pytest.mark.parametrize(
    "overrides, fragment",
    [
        ({"densty": 2.0}, "unknown scenario field(s) ['densty']"),
        ({"density": "high"}, "density must be a finite number"),
        ({"density": math.nan}, "density must be a finite number"),
        ({"lanes": 2.5}, "lanes must be an integer"),
        ({"lanes": True}, "lanes must be an integer"),
        ({"target_speed_fraction": [0.7]}, "target_speed_fraction must be a list of 2 finite numbers"),
        ({"target_speed_fraction": [0.9, 0.7]}, "0 <= lo <= hi <= 1"),
        ({"target_speed_fraction": [-0.1, 1.0]}, "0 <= lo <= hi <= 1"),
        ({"target_speed_fraction": [0.0, 1.5]}, "0 <= lo <= hi <= 1"),
        ({"policy_frequency": 10, "simulation_frequency": 15}, "must be a multiple of policy_frequency"),
        ({"road": "roundabout"}, "road must be one of"),
        ({"duration": -1.0}, "duration must be in (0, 3600] s"),
        ({"acceleration_range": [1.0, 5.0]}, "acceleration_range"),
        ({"steering_range": [-2.0, 2.0]}, "steering_range"),
    ],
)
def test_bad_overrides_raise_clear_errors(overrides, fragment):
    with pytest.raises(ScenarioError) as info:
        apply_overrides(get_scenario("four-lane-d1.0"), overrides)
    assert fragment in str(info.value)


def test_unknown_override_lists_valid_fields():
    with pytest.raises(ScenarioError) as info:
        apply_overrides(get_scenario("merge"), {"speedlimit": 10})
    assert "speed_limit" in str(info.value) and "valid fields" in str(info.value)


def test_two_way_and_merge_keep_two_lanes():
    with pytest.raises(ScenarioError, match="lanes must be 2"):
        get_scenario("two-way").replace(lanes=4)


def test_override_file_then_mapping(tmp_path):
    path = tmp_path / "dense.json"
    path.write_text(json.dumps({"density": 2.7, "duration": 20.0, "vehicles_count": 30}))
    s = resolve_scenario("four-lane-d1.0", config_file=path, overrides={"duration": 5.0})
    assert (s.density, s.duration, s.vehicles_count, s.lanes) == (2.7, 5.0, 30, 4)
    assert load_overrides(path) == {"density": 2.7, "duration": 20.0, "vehicles_count": 30}


@pytest.mark.parametrize(
    "text, fragment", [("{not json", "not valid JSON"), ("[1, 2]", "must hold a JSON object"), ('{"foo": 1}', "unknown")]
)
def test_bad_override_files(tmp_path, text, fragment):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(ScenarioError, match=fragment.replace("(", r"\(")):
        resolve_scenario("two-lane-d1.0", config_file=path)


def test_missing_override_file(tmp_path):
    with pytest.raises(ScenarioError, match="no such file"):
        load_overrides(tmp_path / "nope.json")


def test_to_dict_round_trips():
    s = get_scenario("four-lane-d2.5-slow")
    data = s.to_dict()
    json.dumps(data)
    assert Scenario(**data) == s


def test_timing_properties():
    s = get_scenario("two-lane-d1.0")
    assert s.steps_per_action == s.simulation_frequency // s.policy_frequency
    assert s.num_actions == 500


@pytest.mark.parametrize(
    "overrides, fragment",
    [
        ({"simulation_frequency": 1_000_000_000}, "frequencies must be integers in [1, 1000] Hz"),
        ({"vehicles_count": 100_000}, "vehicles_count must be in [0, 1000]"),
        ({"duration": 1e300}, "duration must be in (0, 3600] s"),
        ({"duration": 1e308}, "duration must be in (0, 3600] s"),
        ({"duration": 0.01}, "must last at least one action"),
        ({"acceleration_range": [-1e300, 1e300]}, "-100 <= lo < 0 < hi <= 100"),
        ({"density": 1e-300}, "density must be in [0.1, 10]"),
        ({"lanes": 1_000_000}, "lanes must be in [1, 16]"),
        ({"speed_limit": 1e30}, "speed_limit must be in (0, 100] m/s"),
        ({"ego_speed": 1e30}, "ego_speed must be in [0, 100] m/s"),
        ({"v_des": 1e30}, "v_des must be in [0, 100] m/s"),
        ({"min_spawn_gap": 1e30}, "min_spawn_gap must be in [0, 1000] m"),
        ({"duration": 3600.0}, "DRIVEOPT_ALLOW_LARGE=1"),
    ],
)
def test_unrunnable_and_degenerate_scenarios_are_refused(monkeypatch, overrides, fragment):
    monkeypatch.delenv("DRIVEOPT_ALLOW_LARGE", raising=False)
    with pytest.raises(ScenarioError) as info:
        apply_overrides(get_scenario("four-lane-d3.0"), overrides)
    assert fragment in str(info.value) and "\n" not in str(info.value)


def test_a_long_episode_runs_when_the_user_allows_large_work(monkeypatch):
    long = {"duration": 3600.0, "vehicles_count": 200}  # 1.4e7 vehicle-steps: hours
    monkeypatch.setenv("DRIVEOPT_ALLOW_LARGE", "1")
    assert apply_overrides(get_scenario("four-lane-d3.0"), long).duration == 3600.0
    monkeypatch.setenv("DRIVEOPT_ALLOW_LARGE", "0")
    with pytest.raises(ScenarioError, match="simulation work per episode"):
        apply_overrides(get_scenario("four-lane-d3.0"), long)


def test_every_registered_scenario_is_within_the_ranges():
    for name in list_scenarios():
        assert Scenario(**get_scenario(name).to_dict()) == get_scenario(name)


@pytest.mark.parametrize(
    "text, fragment",
    [
        ('{"duration": ' + "9" * 400 + "}", "has 400 characters"),
        ("[" * 100_000 + "]" * 100_000, "nested deeper than"),
        ('{"description": "\\ud800"}', "not valid Unicode"),
        ('{"duration": Infinity}', "Infinity is not a JSON number"),
    ],
)
def test_override_files_beyond_the_reader_limits_are_one_line_errors(tmp_path, text, fragment):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(ScenarioError) as info:
        load_overrides(path)
    assert fragment in str(info.value) and str(path) in str(info.value)


def test_a_fifo_as_override_file_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    with pytest.raises(ScenarioError, match="not a regular file .a FIFO."):
        load_overrides(fifo)
