"""Upstream racetrack-v0's road ("f", "g") leaves 8.7 cm between its lanes, which upstream counts as off the road: the
planner's road is the ego's lane alone from RoadPreview.lane_gap_time (at least lane_gap_distance) before that road to
its end, and both lanes before."""

import numpy as np
import pytest

import driveopt
from driveopt.sim.perception import RoadPreview, Task, perceive


@pytest.mark.parametrize("before, lanes", [(35.0, 2), (25.0, 2), (15.0, 1), (-10.0, 1)])
def test_the_lane_is_held_only_from_the_gap_preview_before_a_road_with_a_gap_between_its_lanes(before, lanes):
    env = driveopt.gym_make("racetrack-v0", config={"action": {"type": "ContinuousAction"}})
    try:
        env.reset(seed=0)
        sim = env.unwrapped
        sim.road.vehicles = [sim.vehicle]
        network = sim.road.network
        if before > 0:  # on the arc before that road, at its end less ``before``
            lane = network.get_lane(("e", "f", 1))
            s = lane.length - before
        else:  # on that road
            lane, s = network.get_lane(("f", "g", 1)), -before
        sim.vehicle.position = np.asarray(lane.position(s, 0.0), dtype=float)
        sim.vehicle.heading = lane.heading_at(s)
        sim.vehicle.speed = 10.0  # 2 s of the default preview: 20 m
        sim.vehicle.lane_index = sim.vehicle.target_lane_index = network.get_closest_lane_index(
            sim.vehicle.position, sim.vehicle.heading)
        sim.vehicle.lane = network.get_lane(sim.vehicle.lane_index)
        road = perceive(env, Task(v_des=10.0), RoadPreview()).scene.road
        assert road.num_lanes == lanes
        held = perceive(env, Task(v_des=10.0), RoadPreview(lane_gap_time=4.0, lane_gap_distance=30.0)).scene.road
        assert held.num_lanes == 1  # held from the whole lane preview (40 m): from every one of these places
    finally:
        env.close()
