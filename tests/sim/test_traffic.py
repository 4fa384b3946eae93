"""Neighbour traffic: upstream IDM cars may reverse; the forward-only option stops them at 0 m/s."""

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
