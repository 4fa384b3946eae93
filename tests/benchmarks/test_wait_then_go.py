"""benchmarks/studies/wait_then_go.py: the scripted car drives the route's lanes to the destination, stands at the
junction's entry for the wait it is given, and the study refuses bad arguments."""

from __future__ import annotations

import numpy as np
import pytest

import driveopt
from driveopt.sim import step_hook

from benchmarks.studies import wait_then_go


def _empty_intersection(seed: int = 0):
    env = driveopt.gym_make("intersection-v0", config={"action": {"type": "ContinuousAction"},
                                                     "initial_vehicle_count": 0, "spawn_probability": 0.0})
    env.reset(seed=seed)
    return env


def _drive(env, wait: float, seconds: int) -> tuple[wait_then_go.WaitThenGo, list[float], bool]:
    sim = env.unwrapped
    driver = wait_then_go.WaitThenGo(sim, wait_then_go.RoutePath(sim), wait, 4.5, 7.0)
    step_hook.install(sim.vehicle, driver)
    offsets, on_road = [], True
    for _ in range(seconds):
        env.step(driver.action())
        offsets.append(driver.path.locate(np.asarray(sim.vehicle.position, dtype=float))[1])
        on_road &= bool(sim.vehicle.on_road) and not sim.vehicle.crashed
    return driver, offsets, on_road


def test_without_traffic_the_car_follows_the_left_turn_and_arrives():
    env = _empty_intersection()
    try:
        driver, offsets, on_road = _drive(env, 0.0, 9)
        sim = env.unwrapped
        assert [road for road in driver.path.roads] == [("o0", "ir0"), ("ir0", "il1"), ("il1", "o1")]
        assert on_road and max(offsets) < 1.5  # [m] from the route's lanes
        assert sim.has_arrived(sim.vehicle)
    finally:
        env.close()


def test_the_car_stands_at_the_junctions_entry_until_its_wait_has_passed():
    env = _empty_intersection()
    try:
        sim = env.unwrapped
        entry = sim.road.network.get_lane(("o0", "ir0", 0))
        driver, _, on_road = _drive(env, 6.0, 5)
        front = entry.local_coordinates(np.asarray(sim.vehicle.position, dtype=float))[0] + 0.5 * sim.vehicle.LENGTH
        assert on_road and sim.vehicle.speed < 1.5  # [m/s] all but standing at 5 s (IDM closes in slowly)
        assert entry.length - 3.0 < front <= entry.length + 0.5  # [m] its front at the entry's end
        for _ in range(4):  # the wait over, it goes
            env.step(driver.action())
        assert sim.vehicle.speed > 5.0
    finally:
        env.close()


@pytest.mark.parametrize("args", [["--episodes", "0"], ["--waits-step", "0"], ["--acceleration", "-1"],
                                  ["--inside", "1.5"],
                                  ["--envs", "highway-v0"]])
def test_bad_arguments_are_refused(tmp_path, args):
    with pytest.raises(SystemExit) as exc:
        wait_then_go.main(["--out", str(tmp_path / "o.json"), *args])
    assert exc.value.code == 2


def test_a_second_stop_holds_the_car_inside_the_junction_until_its_wait():
    env = _empty_intersection()
    try:
        sim = env.unwrapped
        path = wait_then_go.RoutePath(sim)
        stop = path.wait_s + 0.5 * path.junction_length  # [m] half way through the left turn
        driver = wait_then_go.WaitThenGo(sim, path, 0.0, 4.5, 7.0, (stop, 7.0))
        step_hook.install(sim.vehicle, driver)
        for _ in range(6):
            env.step(driver.action())
        s = path.locate(np.asarray(sim.vehicle.position, dtype=float))[0] + 0.5 * sim.vehicle.LENGTH
        assert sim.vehicle.speed < 1.5 and stop - 3.0 < s <= stop + 0.5  # [m] its front at the stop
        assert not sim.vehicle.crashed and sim.vehicle.on_road
    finally:
        env.close()
