"""Each car of a highway-env road reaches the planner with the centre of the lane it steers to (its target lane) in the
frame, where its predicted lateral motion ends (RoadPreview.target_lanes); the papers' loop leaves it out (P1)."""

import numpy as np

import driveopt
from driveopt.drivers.optimiser import DRIVEOPT_LOOP, PAPERS_LOOP
from driveopt.sim.perception import RoadPreview, Task, perceive


def test_each_car_is_given_its_target_lanes_centre_and_the_papers_loop_none():
    assert DRIVEOPT_LOOP.target_lanes and not PAPERS_LOOP.target_lanes
    env = driveopt.gym_make("racetrack-v0", config={"action": {"type": "ContinuousAction"}})
    try:
        env.reset(seed=0)
        scene = perceive(env, Task(v_des=10.0), RoadPreview()).scene
        road = scene.road
        centres = road.first_lane_center + road.lane_width * np.arange(road.num_lanes)
        cars = [n for n in scene.neighbours if n.lane_center is not None]
        assert cars  # the cars near the ego, on its road's lanes
        for n in cars:  # the centre of one of the road's lanes, the car within half a lane of it
            assert np.min(np.abs(centres - n.lane_center)) < 0.05
            assert abs(n.y - n.lane_center) < 0.5 * road.lane_width
        p1 = perceive(env, Task(v_des=10.0), RoadPreview(target_lanes=False)).scene
        assert all(n.lane_center is None for n in p1.neighbours)
        assert [(n.x, n.y, n.vy) for n in p1.neighbours] == [(n.x, n.y, n.vy) for n in scene.neighbours]
    finally:
        env.close()
