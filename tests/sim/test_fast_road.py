"""FastRoad simulates exactly what upstream's Road does: neighbour searches, collisions, whole episodes."""

import numpy as np
import pytest
from highway_env.road.lane import StraightLane
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle

from driveopt.experiments.rollout import Rollout
from driveopt.registry import get_planner
from driveopt.sim.fast_road import FastRoad, along_x


def _roads(positions, speeds, lanes=4):
    """The same vehicles on an upstream Road and on a FastRoad (separate copies)."""
    roads = []
    for cls in (Road, FastRoad):
        road = cls(network=RoadNetwork.straight_road_network(lanes), np_random=np.random.RandomState(0))
        for p, v in zip(positions, speeds):
            road.vehicles.append(IDMVehicle(road, np.array(p, dtype=float), heading=0.0, speed=float(v)))
        roads.append(road)
    return roads


def test_neighbours_match_upstream_including_ties_and_lanes_of_others():
    rng = np.random.default_rng(3)
    x = np.round(rng.uniform(0, 120, 40))  # rounded: many equal longitudinal positions (ties)
    y = rng.choice([0.0, 4.0, 8.0, 12.0, 6.1, 13.9], 40)  # some between lanes, some at the outer margin
    upstream, fast = _roads(np.stack([x, y], 1), rng.uniform(5, 20, 40))
    assert any(np.sum(x == xi) > 1 for xi in x)
    lanes = upstream.network.lanes_list()
    for i in range(40):
        for k in range(len(lanes)):
            index = ("0", "1", k)
            expected = upstream.neighbour_vehicles(upstream.vehicles[i], index)
            got = fast.neighbour_vehicles(fast.vehicles[i], index)
            assert [upstream.vehicles.index(v) if v else None for v in expected] == [fast.vehicles.index(v) if v else None for v in got]


def test_neighbours_of_a_vehicle_not_on_the_road():
    upstream, fast = _roads([[10, 0], [30, 0], [50, 4]], [10, 10, 10])
    probe = [IDMVehicle(road, np.array([20.0, 0.0]), speed=10.0) for road in (upstream, fast)]
    expected = upstream.neighbour_vehicles(probe[0])
    got = fast.neighbour_vehicles(probe[1])
    assert [upstream.vehicles.index(v) for v in expected] == [fast.vehicles.index(v) for v in got] == [1, 0]


def test_collisions_match_upstream():
    # A fast car runs into a slow one; a pair side by side in adjacent lanes; a far car.
    positions = [[0, 0], [12, 0], [40, 4], [41, 7.5], [300, 8]]
    speeds = [25, 2, 10, 10, 10]
    upstream, fast = _roads(positions, speeds)
    for _ in range(30):
        for road in (upstream, fast):
            road.act()
            road.step(1 / 15)
        assert [v.crashed for v in upstream.vehicles] == [v.crashed for v in fast.vehicles]
        assert all(np.array_equal(a.position, b.position) for a, b in zip(upstream.vehicles, fast.vehicles))
    assert upstream.vehicles[0].crashed and upstream.vehicles[1].crashed and not upstream.vehicles[4].crashed


@pytest.mark.parametrize("scenario", ["four-lane-d3.0", "p2-four-lane-d1.5"])
def test_whole_episode_is_identical_to_upstream(scenario, monkeypatch):
    def states(seed):
        rollout = Rollout(scenario, get_planner("idm").driver(), seed=seed, duration=3.0)
        out = []
        for step in rollout:
            road = step.env.unwrapped.road
            out.append(np.array([[*v.position, v.speed, v.heading, v.crashed] for v in road.vehicles]))
        return type(road), out

    fast_type, fast = states(11)
    monkeypatch.setattr(FastRoad, "like", classmethod(lambda cls, road: road))
    upstream_type, upstream = states(11)
    assert fast_type is FastRoad and upstream_type is Road
    assert len(fast) == len(upstream) and all(np.array_equal(a, b) for a, b in zip(fast, upstream))


def test_only_lanes_along_x_take_the_array_path():
    assert along_x(StraightLane([0, 4], [100, 4]))
    assert not along_x(StraightLane([0, 0], [100, 1]))
