"""driveopt.drivers.commands: driveopt's exact tracking and P2's authors' first-nodes mean, on trajectories whose
commands are known in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from driveopt.drivers.commands import EXACT_TRACKING, P2_AUTHORS_COMMAND, FirstNodesMean
from driveopt.drivers.optimiser import ClosedLoop
from driveopt.sim.control import BicycleModel, ControlError, EgoKinematics, track
from driveopt.trajectory import Trajectory

MODEL = BicycleModel()  # highway-env's defaults: +-5 m/s^2, +-pi/4 rad


def _trajectory(t, x, y, vx, vy, ax, ay) -> Trajectory:
    speed = np.hypot(vx, vy)
    curvature = (vx * ay - vy * ax) / np.maximum(speed, 1e-3) ** 3
    return Trajectory(t, x, y, vx, vy, ax, ay, speed, np.arctan2(vy, vx), curvature, (vx * ax + vy * ay) / speed)


def _braking(v0: float, deceleration: float) -> Trajectory:
    t = np.linspace(0.0, 5.0, 101)
    v = v0 - deceleration * t
    zero = np.zeros_like(t)
    return _trajectory(t, v0 * t - 0.5 * deceleration * t**2, zero, v, zero, np.full_like(t, -deceleration), zero)


def _arc(speed: float, radius: float) -> Trajectory:
    t = np.linspace(0.0, 5.0, 101)
    angle = speed * t / radius
    return _trajectory(t, radius * np.sin(angle), radius * (1 - np.cos(angle)), speed * np.cos(angle),
                       speed * np.sin(angle), -speed**2 / radius * np.sin(angle), speed**2 / radius * np.cos(angle))


def test_a_plan_at_the_cars_speed_straight_ahead_commands_nothing():
    command = P2_AUTHORS_COMMAND(_braking(10.0, 0.0), 0.0, EgoKinematics(10.0, 0.0), MODEL)
    assert command.acceleration == pytest.approx(0.0, abs=1e-6) and command.steering == pytest.approx(0.0, abs=1e-6)
    assert not command.saturated


def test_braking_is_the_mean_speed_change_over_the_first_nodes_passed_on_unscaled():
    # The mean speed of the first 8 nodes (0 to 1.05 s) of a 1 m/s^2 braking plan is 10 - 0.525 m/s; over 1.05 s that
    # asks -0.5 m/s^2, which the simulator reads as half its braking range: -2.5 m/s^2.
    command = P2_AUTHORS_COMMAND(_braking(10.0, 1.0), 0.0, EgoKinematics(10.0, 0.0), MODEL)
    assert command.action[0] == pytest.approx(-0.5, abs=1e-5)
    assert command.acceleration == pytest.approx(-2.5, abs=1e-4)
    later = P2_AUTHORS_COMMAND(_braking(10.0, 1.0), 1.0, EgoKinematics(9.0, 0.0), MODEL)  # read from 1 s on
    assert later.action[0] == pytest.approx(-0.5, abs=1e-5)


def test_a_steady_arc_steers_at_the_wheel_base_angle_scaled_by_the_range():
    radius = 50.0
    command = P2_AUTHORS_COMMAND(_arc(10.0, radius), 0.0, EgoKinematics(10.0, 0.0), MODEL)
    expected = math.atan(2.875 / radius)
    assert command.action[1] == pytest.approx(expected, rel=1e-4)
    assert command.steering == pytest.approx(expected * math.pi / 4, rel=1e-4)
    assert command.acceleration == pytest.approx(0.0, abs=1e-4)


def test_commands_beyond_the_range_are_clipped_and_flagged():
    command = P2_AUTHORS_COMMAND(_braking(10.0, 0.0), 0.0, EgoKinematics(20.0, 0.0), MODEL)
    assert command.action[0] == -1.0 and command.acceleration == -5.0 and command.saturated


def test_bad_settings_and_states_are_refused():
    with pytest.raises(ControlError):
        FirstNodesMean(nodes=1)
    with pytest.raises(ControlError):
        P2_AUTHORS_COMMAND(_braking(10.0, 0.0), math.nan, EgoKinematics(10.0, 0.0), MODEL)


def test_driveopt_loop_tracks_exactly():
    plan, state = _arc(10.0, 50.0), EgoKinematics(9.0, 0.05)
    assert ClosedLoop().command is EXACT_TRACKING
    ours, reference = EXACT_TRACKING(plan, 0.2, state, MODEL), track(plan, 0.2, state, MODEL)
    assert np.array_equal(ours.action, reference.action) and ours[:2] == reference[:2]
