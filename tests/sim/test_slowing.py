"""A car faster than its desired speed slows to it gently where no curve lowers that speed (Scene.slowing), at once
where one does."""

import pytest

import driveopt
from driveopt.sim.perception import RoadPreview, Task, perceive


@pytest.mark.parametrize("env_id, v_des, slowing", [
    ("merge-v0", 20.0, 1.5),  # a straight road: upstream starts the car at 30 m/s in 20 m/s lanes
    ("racetrack-v0", 20.0, 0.0),  # a curve ahead lowers 20 m/s: slowed for at once
])
def test_the_scene_asks_for_gentle_slowing_only_where_no_curve_lowers_the_desired_speed(env_id, v_des, slowing):
    env = driveopt.gym_make(env_id, config={"action": {"type": "ContinuousAction"}})
    try:
        env.reset(seed=0)
        scene = perceive(env, Task(v_des=v_des), RoadPreview(slowing=1.5)).scene
        assert (scene.v_des < v_des) == (slowing == 0.0)  # the curve ahead lowered it, or nothing did
        assert scene.slowing == slowing
        assert perceive(env, Task(v_des=v_des)).scene.slowing == 0.0  # the preview's default: at once
    finally:
        env.close()
