"""The contact guard: exact rectangle contact, rollouts with upstream's model, and when it brakes."""

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import box_corners, boxes_overlap
from hypothesis import given, settings
from hypothesis import strategies as st

from driveopt.planner import PlanResult, PlanStatus
from driveopt.registry import get_planner
from driveopt.scene import EgoState, Neighbour, Road, Scene
from driveopt.sim.contact import CONTACT_MARGIN, GUARD_SPEED, MIN_HORIZON, Boxes, clearance, guard, rollout, separation
from driveopt.sim.control import BicycleModel, Command, EgoKinematics, predict, to_action
from driveopt.trajectory import Trajectory

MODEL = BicycleModel()
coordinate = st.floats(-6.0, 6.0)
angle = st.floats(-math.pi, math.pi)
size = st.floats(0.5, 6.0)


@settings(max_examples=300, deadline=None)
@given(coordinate, coordinate, angle, angle, size, size, size, size)
def test_separation_agrees_with_the_corner_test(x, y, ha, hb, la, wa, lb, wb):
    """Separation's sign and the corner-projection test of conftest answer alike (away from exact touching); a
    positive separation is a gap: moving one box that far along the line of centres cannot make them overlap."""
    b = box_corners(x, y, hb, lb, wb)
    touching = boxes_overlap(box_corners(0.0, 0.0, ha, la + 1e-6, wa + 1e-6), b) != boxes_overlap(
        box_corners(0.0, 0.0, ha, la - 1e-6, wa - 1e-6), b)
    gap = float(separation(Boxes(0.0, 0.0, ha, 0.5 * la, 0.5 * wa), Boxes(x, y, hb, 0.5 * lb, 0.5 * wb)))
    assert touching or (gap <= 0.0) == boxes_overlap(box_corners(0.0, 0.0, ha, la, wa), b)
    if gap > 1e-6:
        d = np.hypot(x, y)
        closer = (1.0 - (gap - 1e-6) / d) if d > 0 else 1.0
        assert not boxes_overlap(box_corners(0.0, 0.0, ha, la, wa), box_corners(x * closer, y * closer, hb, lb, wb))


def test_rollout_follows_upstreams_model_then_brakes_to_a_standstill():
    state = EgoKinematics(speed=2.0, heading=0.2)
    t, x, y, heading = rollout(state, 1.0, 0.3, MODEL, until=0.0)
    moved, after = predict(state, 1.0, 0.3, MODEL)  # the command's period, as the controller predicts it
    k = MODEL.steps_per_action
    np.testing.assert_allclose([x[k], y[k], heading[k]], [moved[0], moved[1], after.heading], atol=1e-12)
    # then the hardest braking: 2.1 m/s from -5 m/s^2 stops within 0.45 s, and the car never reverses
    assert t[-1] == pytest.approx(k * MODEL.simulation_dt + 0.45, abs=MODEL.simulation_dt)
    step = np.hypot(np.diff(x), np.diff(y))
    assert np.all(np.diff(step[k:]) <= 1e-12) and step[-1] <= 5.0 * MODEL.simulation_dt ** 2  # last step from < 5 dt m/s
    # by default it then stands still until MIN_HORIZON
    t_long, x_long, y_long, _ = rollout(state, 1.0, 0.3, MODEL)
    assert t_long[-1] == pytest.approx(MIN_HORIZON) and np.all(x_long[len(t):] == x[-1]) and np.all(y_long[len(t):] == y[-1])


def _beside_a_stopped_car(gap_x: float, speed: float = 0.0, follower: Neighbour | None = None) -> Scene:
    """The ego turned 0.3 rad towards a stopped car ahead on its right (P2 Fig. 7 dense road, episode 24)."""
    cars = (Neighbour(x=100.0 + gap_x, y=3.8, yaw=0.0),) + ((follower,) if follower else ())
    return Scene(ego=EgoState(x=100.0, y=6.0, vx=speed, yaw=-0.3), road=Road(num_lanes=4), neighbours=cars)


def _command(acceleration: float, steering: float) -> Command:
    return Command(acceleration, steering, to_action(acceleration, steering, MODEL), False)


def test_guard_stops_a_crawl_that_would_push_the_corner_into_a_stopped_car():
    """Pulling away to the left with full steering still moves the body along its heading first: 1 cm later the
    front corner touches. Standing still touches nothing, so the guard holds the car."""
    scene, state = _beside_a_stopped_car(4.75), EgoKinematics(speed=0.0, heading=-0.3)
    command = _command(2.3, 0.78)
    t, x, y, heading = rollout(state, command.acceleration, command.steering, MODEL)
    other = box_corners(4.75, -2.2, 0.0, 5.0, 2.0)
    assert any(boxes_overlap(box_corners(x[i], y[i], heading[i], 5.0, 2.0), other) for i in range(len(t)))
    assert not boxes_overlap(box_corners(0.0, 0.0, -0.3, 5.0, 2.0), other)

    guarded, replaced = guard(command, state, scene, MODEL)
    assert replaced and guarded.acceleration == 0.0 and guarded.steering == command.steering
    assert 0.0 < clearance(*rollout(state, guarded.acceleration, guarded.steering, MODEL), scene) < CONTACT_MARGIN


def test_guard_brakes_a_crawling_car_as_hard_as_it_can_without_reversing():
    state = EgoKinematics(speed=0.25, heading=-0.3)
    guarded, replaced = guard(_command(-0.5, 0.78), state, _beside_a_stopped_car(4.78), MODEL)
    assert replaced and guarded.acceleration == pytest.approx(-0.25 / MODEL.action_period)


@pytest.mark.parametrize("case", ["clear", "fast", "follower"])
def test_guard_leaves_commands_alone(case):
    """Room to move; above GUARD_SPEED (the planner's bounds apply); a car closing from behind, which braking now
    would meet sooner."""
    command = _command(2.3, 0.78)
    if case == "clear":
        scene, state = _beside_a_stopped_car(5.5), EgoKinematics(0.0, -0.3)
    elif case == "fast":
        scene, state = _beside_a_stopped_car(7.0, speed=GUARD_SPEED + 0.5), EgoKinematics(GUARD_SPEED + 0.5, -0.3)
    else:
        follower = Neighbour(x=93.0, y=6.0, vx=6.0, yaw=0.0)
        scene, state = _beside_a_stopped_car(30.0, follower=follower), EgoKinematics(0.0, 0.0)
        command = _command(4.0, 0.0)
        assert clearance(*rollout(state, 0.0, 0.0, MODEL), scene) < 0.0  # standing, it is hit
    kept, replaced = guard(command, state, scene, MODEL)
    assert kept is command and not replaced


def _accelerating_plan() -> Trajectory:
    t = np.linspace(0.0, 5.0, 101)
    x, v, a = 1.15 * t ** 2, 2.3 * t, np.full_like(t, 2.3)
    zero = np.zeros_like(t)
    return Trajectory(t=t, x=x, y=zero, vx=v, vy=zero, ax=a, ay=zero, speed=v, heading=zero, curvature=zero, acceleration=a)


@pytest.mark.parametrize("contact_guard", [False, True])
def test_the_driver_guards_only_when_configured(contact_guard):
    plan_ = _accelerating_plan()
    result = PlanResult(**dict.fromkeys(PlanResult._fields))._replace(
        status=PlanStatus.SUCCESS, trajectory=plan_, fallback=plan_, fallback_deceleration=3.0)
    grid = get_planner("grid")
    spec = dataclasses.replace(grid, loop=dataclasses.replace(grid.loop, contact_guard=contact_guard))
    assert get_planner("grid").loop.contact_guard and not get_planner("grid-p1").loop.contact_guard
    driver = spec.driver()
    driver.model = MODEL
    env = SimpleNamespace(unwrapped=SimpleNamespace(vehicle=SimpleNamespace(speed=0.0)))
    now = EgoKinematics(0.0, -0.3)  # a straight road along +x: world and road frame agree
    perception = SimpleNamespace(kinematics=now, scene=_beside_a_stopped_car(4.75))
    command, guarded = driver._command(result, driver.followed(result), 0.0, now, env, perception)
    action = command.action
    assert guarded == contact_guard
    assert (action[0] == 0.0) == contact_guard  # [-1, 1] action: 0 is no acceleration
