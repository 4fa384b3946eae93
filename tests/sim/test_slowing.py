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


def test_the_most_asked_for_comes_down_at_the_slowing_rate_from_the_start_speed():
    """The driver's memory of the most a plan is asked for (OptimiserDriver._let_slow): from the car's 30 m/s at the
    first scene down at 1.5 m/s^2, to v_des; a car that started at v_des is asked for v_des whatever it overshoots;
    where a curve lowers v_des (scene.slowing 0), v_des at once and after."""
    from types import SimpleNamespace

    from driveopt import EgoState, Scene
    from driveopt.drivers.optimiser import OptimiserDriver

    def most(driver, time, speed, v_des=20.0, slowing=1.5):
        env = SimpleNamespace(unwrapped=SimpleNamespace(time=time))
        scene = Scene(ego=EgoState(x=0.0, y=0.0, vx=speed), v_des=v_des, slowing=slowing)
        return OptimiserDriver._let_slow(driver, env, scene).slowing_from

    def fresh():
        return SimpleNamespace(_slowing_from=0.0, _slowing_at=None)

    driver = fresh()
    assert most(driver, 0.0, 30.0) == 30.0
    assert most(driver, 2.0, 25.0) == pytest.approx(27.0)  # 30 - 1.5 x 2, whatever the car's speed now
    assert most(driver, 10.0, 20.3) == 20.0  # down to v_des, and no higher after
    assert most(driver, 11.0, 21.0) == 20.0
    started_at_v_des = fresh()
    assert most(started_at_v_des, 0.0, 10.0, v_des=10.0) == 10.0 and most(started_at_v_des, 1.0, 10.5, v_des=10.0) == 10.0
    curve = fresh()
    assert most(curve, 0.0, 30.0, slowing=0.0) == 20.0 and most(curve, 1.0, 30.0) == 20.0


def test_the_controller_asks_merge_v0s_car_for_its_start_speed_first():
    env = driveopt.gym_make("merge-v0", config={"action": {"type": "ContinuousAction"}})
    try:
        env.reset(seed=0)
        controller = driveopt.Controller("bilevel", verbose=False)
        controller.reset(env, seed=0)
        controller.act(env)
        problem = controller.last.problem
        assert float(problem.v_des) == 20.0 and float(problem.slowing) == 1.5
        assert 29.0 < float(problem.slowing_from) <= 30.0  # the first plan of the policy step: the car at 30 m/s
    finally:
        env.close()
