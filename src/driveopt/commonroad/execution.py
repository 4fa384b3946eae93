"""Execution model ``tracked``: the ego is driveopt's kinematic bicycle, following each plan with driveopt's tracker.

The same model and tracker as driveopt's highway-env closed loop (:mod:`driveopt.sim.control`): at every time step
(0.1 s) the plan (road frame) is turned into world coordinates (:func:`driveopt.sim.world_plan.to_world`), and
:func:`~driveopt.sim.control.track` computes the one command (acceleration, steering) that makes the bicycle end the
step at the plan's speed and follow its course; the command is held for the step and the bicycle integrated over it
at :data:`SUBSTEP` (:func:`~driveopt.sim.control.predict`: the centre moves along ``heading + beta``, ``beta =
arctan(tan(steering) / 2)``, the heading turns at ``v sin(beta) / (wheelbase / 2)``). When the plan is not SUCCESS
its fallback is followed and braked at once (:func:`~driveopt.sim.control.brake_at_least`), as in highway-env. The
state after the step is the ego's next state: the evaluator checks it, and the next plan starts from it (its road-frame
rates from :func:`driveopt.sim.road_frame.frame_rates`).

The car's limits (CommonRoad's parameters of the ego's vehicle, ``VW_VANAGON``): acceleration within +-``a_max``
(11.5 m/s^2), steering within its range (+-1.023 rad), the wheelbase ``a + b`` (2.47 m) as the bicycle's length (the
model's reference point midway between the axles, taken for the box's centre). Not modelled: the steering rate limit,
the friction circle, ``v_switch``'s engine limit.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from driveopt.commonroad.evaluate import EgoPose
from driveopt.commonroad.path import PathFrame
from driveopt.scene import EgoState
from driveopt.sim.control import (BicycleModel, Command, EgoKinematics, brake_at_least, predict, sample_trajectory,
                                  steering_for_slip, track)
from driveopt.sim.lane_graph import wrap_angle
from driveopt.sim.road_frame import frame_rates, slip_angle
from driveopt.sim.world_plan import WorldTrajectory, to_world

SUBSTEP = 0.01  # [s] integration step of the bicycle within one time step


class Car(NamedTuple):
    """The tracked ego in world coordinates."""

    x: float  # [m] centre
    y: float  # [m]
    heading: float  # [rad] body heading, world axes
    speed: float  # [m/s]
    acceleration: float  # [m/s^2] the command held over the last step
    steering: float  # [rad] front-wheel angle held over the last step (its slip angle sets the course)


def vehicle_model(params: Any, dt: float, substep: float = SUBSTEP) -> BicycleModel:
    """The bicycle for CommonRoad vehicle parameters ``params`` (``l``, ``a``, ``b`` [m], ``longitudinal.a_max``
    [m/s^2], ``steering.min``/``max`` [rad]), one command held per time step ``dt`` [s], integrated at ``substep`` [s]
    (``dt`` a whole multiple of it, to 1e-9)."""
    steps = int(round(dt / substep))
    if steps < 1 or abs(steps * substep - dt) > 1e-9:
        raise ValueError(f"the time step {dt} s is not a whole multiple of the substep {substep} s")
    a_max = float(params.longitudinal.a_max)
    return BicycleModel(length=float(params.a) + float(params.b), acceleration_range=(-a_max, a_max),
                        steering_range=(float(params.steering.min), float(params.steering.max)),
                        simulation_dt=dt / steps, steps_per_action=steps)


class WorldAxes:
    """A :class:`~driveopt.commonroad.path.PathFrame` read as :func:`driveopt.sim.world_plan.to_world` reads a road
    frame: ``to_world(s, d)`` -> (X, Y [m], the path's heading [rad], its curvature [1/m], the offset ``d`` [m])."""

    def __init__(self, frame: PathFrame) -> None:
        self.frame = frame

    def to_world(self, s: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, ...]:
        s, d = np.asarray(s, dtype=np.float64), np.asarray(d, dtype=np.float64)
        xy = self.frame.to_world(s, d)
        return xy[..., 0], xy[..., 1], self.frame.heading(s), self.frame.curvature(s), d


def initial_car(state: Any) -> Car:
    """The tracked car at a CommonRoad initial state (position, orientation, velocity; acceleration and slip angle
    when given, else 0)."""
    value = lambda name: float(getattr(state, name, 0.0) or 0.0) if state.has_value(name) else 0.0  # noqa: E731
    x, y = (float(v) for v in state.position)
    return Car(x, y, float(state.orientation), value("velocity"), value("acceleration"),
               steering_for_slip(value("slip_angle")))


def frame_state(car: Car, frame: PathFrame, model: BicycleModel, length: float, width: float) -> EgoState:
    """The car as the planner's :class:`~driveopt.scene.EgoState` in ``frame``: (s, d) of its centre, the rates of its
    course and of the acceleration it applies (``a`` along the course, ``v^2 sin(beta) / (wheelbase / 2)`` across),
    its body heading relative to the frame as ``yaw``; ``length``, ``width`` [m] of its box."""
    s, d = frame.project(np.array([car.x, car.y]))
    s, d = float(s), float(d)
    theta, kappa = float(frame.heading(np.array(s))), float(frame.curvature(np.array([s]))[0])
    heading = wrap_angle(car.heading - theta)
    beta = slip_angle(car.steering)
    a_n = car.speed * car.speed * math.sin(beta) / (0.5 * model.length)
    vx, vy, ax, ay, _ = frame_rates(heading, car.speed, beta, car.acceleration, a_n, kappa, d)
    return EgoState(x=s, y=d, vx=vx, vy=vy, ax=ax, ay=ay, length=length, width=width, yaw=heading)


def follow(car: Car, plan: WorldTrajectory, model: BicycleModel, brake: float | None = None) -> tuple[Car, Command]:
    """(the car one time step later, the command held): ``plan`` (world coordinates, planned now) tracked over the
    step; ``brake`` [m/s^2]: when given (a fallback followed), the command brakes at least that hard."""
    now = EgoKinematics(speed=car.speed, heading=car.heading)
    command = track(plan, 0.0, now, model)
    if brake is not None:
        command = brake_at_least(command, brake, model, car.speed)
    moved, after = predict(now, command.acceleration, command.steering, model)
    return Car(car.x + float(moved[0]), car.y + float(moved[1]), wrap_angle(after.heading), max(after.speed, 0.0),
               command.acceleration, command.steering), command


def step(car: Car, trajectory: Any, frame: PathFrame, model: BicycleModel,
         brake: float | None = None) -> tuple[Car, float]:
    """(the car one time step after following ``trajectory`` (road frame: t, x = s, y = d, vx, vy, ax, ay) in
    ``frame`` (see :func:`follow`), its distance [m] from where the trajectory is at the step's end)."""
    plan = to_world(trajectory, WorldAxes(frame))
    after = follow(car, plan, model, brake)[0]
    there = sample_trajectory(plan, np.array([model.action_period]))
    return after, math.hypot(after.x - float(there.x[0]), after.y - float(there.y[0]))


def car_pose(step_index: int, car: Car) -> EgoPose:
    """The evaluator's pose of the car at time step ``step_index``: its box turned by the body heading."""
    return EgoPose(step_index, car.x, car.y, car.heading, car.speed, car.acceleration)
