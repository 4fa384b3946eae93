"""Neighbour traffic: upstream IDM cars may reverse; the forward-only option stops them at 0 m/s; P2's target speeds."""

import numpy as np
import pytest

from driveopt.sim.env import make_env
from driveopt.sim.scenarios import ScenarioError, get_scenario
from driveopt.sim.traffic import ForwardIDMVehicle


@pytest.mark.parametrize("reverses", [True, False])
def test_a_hard_braking_neighbour_reverses_only_in_upstream_traffic(reverses):
    scenario = get_scenario("two-lane-d1.0").replace(traffic_reverses=reverses)
    env = make_env(scenario)
    try:
        env.reset(seed=1)
        others = [v for v in env.unwrapped.road.vehicles if v is not env.unwrapped.vehicle]
        assert others and all(isinstance(v, ForwardIDMVehicle) != reverses for v in others)
        car = others[0]
        car.speed = 0.05  # [m/s]
        car.action = {"steering": 0.0, "acceleration": -6.0}  # [m/s^2] braking for a stopped leader
        car.step(0.05)  # [s]
        assert (car.speed < 0.0) == reverses and car.speed >= (-0.3 if reverses else 0.0)
    finally:
        env.close()


def test_traffic_reverses_is_a_strict_bool():
    with pytest.raises(ScenarioError, match="traffic_reverses must be true or false"):
        get_scenario("two-lane-d1.0").replace(traffic_reverses="no")


def _target_speeds(scenario, seed):
    env = make_env(scenario)
    try:
        env.reset(seed=seed)
        sim = env.unwrapped
        others = [v for v in sim.road.vehicles if v is not sim.vehicle]
        return np.array([v.target_speed for v in others]), np.array([v.speed for v in others])
    finally:
        env.close()


@pytest.mark.parametrize("name, limit", [("p2-four-lane-d3.0", 15.0), ("p2-four-lane-d1.5-slow", 7.0)])
def test_p2_neighbours_choose_target_speeds_uniformly_between_zero_and_the_limit(name, limit):
    scenario = get_scenario(name).replace(vehicles_count=40)
    targets, speeds = _target_speeds(scenario, seed=5)
    assert len(targets) == 40 and np.all((targets >= 0.0) & (targets <= limit))
    np.testing.assert_array_equal(speeds, targets)  # each starts at its target speed
    assert len(np.unique(targets)) == len(targets)  # drawn, not one value
    # spread over [0, limit], not P1's 0.7-0.8 x limit: 40 uniform draws leave each third empty with p = 3e-7
    assert np.any(targets < limit / 3) and np.any(targets > 2 * limit / 3)
    again, _ = _target_speeds(scenario, seed=5)
    np.testing.assert_array_equal(again, targets)  # same episode seed, same traffic speeds
    other, _ = _target_speeds(scenario, seed=6)
    assert not np.array_equal(other, targets)


def test_a_target_speed_fraction_outside_zero_to_one_is_refused():
    with pytest.raises(ScenarioError, match=r"target_speed_fraction must be \(lo, hi\) with 0 <= lo <= hi <= 1"):
        get_scenario("p2-four-lane-d3.0").replace(target_speed_fraction=[0.0, 1.2])
    with pytest.raises(ScenarioError, match="target_speed_fraction must be a list of 2 finite numbers"):
        get_scenario("p2-four-lane-d3.0").replace(target_speed_fraction="uniform")
