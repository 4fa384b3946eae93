"""From a planned trajectory to highway-env ``ContinuousAction`` commands, by inverting upstream's model.

Upstream (``highway_env/vehicle/kinematics.py``, ``Vehicle.step``) integrates, per simulation
step ``h`` with the action held, in this order::

    beta    = arctan(tan(delta) / 2)                      # slip angle of the centre
    p      += v * (cos(psi + beta), sin(psi + beta)) * h   # the centre moves along the course psi + beta
    psi    += v * sin(beta) / (L / 2) * h                  # L = Vehicle.LENGTH = 5 m
    v      += a * h

and ``ContinuousAction`` maps ``action`` in [-1, 1]^2 linearly onto ``acceleration_range``
[m/s^2] and ``steering_range`` [rad] (``utils.lmap``), clipping first.

:func:`track` inverts that map over one action period (``n = steps_per_action`` steps):

- ``a`` makes the speed after the period equal the planned speed at its end:
  ``a = (v_plan(t + n h) - v) / (n h)``;
- ``beta`` makes the speed-weighted mean course over the period's steps equal the planned
  course ``atan2(vy, vx)`` at each step's midpoint, with the body heading advancing as upstream
  integrates it (one monotone scalar equation, solved by bisection); ``delta = arctan(2 tan(beta))``;
- with one simulation step per action (lane-keeping-v0: 10 Hz simulation and policy), ``beta`` makes
  the course after the step, ``psi + v sin(beta) / (L/2) h + beta`` (the heading turned, ``beta``
  held), equal the planned course at the period's end: the next plan starts from that course
  (:mod:`driveopt.sim.perception` reads the course of the steering applied), and matching the step's
  own course instead hands every replan the step's turn of the heading on top, a course error that
  grows from plan to plan (the car weaves across its lane). The step's own course lags the plan
  by that turn.

This is the exact discrete inverse, not a feedback law: it uses the current speed and body
heading but never the position error. Commands beyond the action ranges are clipped and
flagged ``saturated``. Note the reachable curvature, ``2 sin(beta_max) / L`` = 0.179 1/m for
the default ±pi/4 steering range.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from driveopt.errors import DriveoptError
from driveopt.sim.lane_graph import wrap_angle
from driveopt.sim.road_frame import slip_angle
from driveopt.trajectory import Trajectory

_BISECTION_STEPS = 60  # halves the slip-angle bracket (< 1 rad) down to ~1e-18 rad


class ControlError(DriveoptError):
    """The env's action space or the trajectory cannot be tracked (wrong action type, shapes, NaN)."""


@dataclass(frozen=True)
class BicycleModel:
    """Upstream's ego model and action mapping; :meth:`from_env` reads every field from a live env."""

    length: float = 5.0  # [m] Vehicle.LENGTH: heading rate v sin(beta) / (length / 2)
    acceleration_range: tuple[float, float] = (-5.0, 5.0)  # [m/s^2] action[0] = -1 .. 1
    steering_range: tuple[float, float] = (-math.pi / 4, math.pi / 4)  # [rad] action[1] = -1 .. 1
    simulation_dt: float = 0.05  # [s] one simulation step (1 / simulation_frequency)
    steps_per_action: int = 2  # [-] simulation steps an action is held (simulation // policy frequency)

    def __post_init__(self) -> None:
        object.__setattr__(self, "acceleration_range", tuple(float(v) for v in self.acceleration_range))
        object.__setattr__(self, "steering_range", tuple(float(v) for v in self.steering_range))
        if not (self.length > 0 and self.simulation_dt > 0 and self.steps_per_action >= 1):
            raise ControlError("length [m], simulation_dt [s] and steps_per_action must be positive")
        if not self.acceleration_range[0] < self.acceleration_range[1]:
            raise ControlError(f"acceleration_range must be increasing, got {self.acceleration_range}")
        if not -math.pi / 2 < self.steering_range[0] < self.steering_range[1] < math.pi / 2:
            raise ControlError(f"steering_range must be increasing within (-pi/2, pi/2), got {self.steering_range}")

    @property
    def action_period(self) -> float:
        """[s] time one action is held."""
        return self.simulation_dt * self.steps_per_action

    @property
    def slip_range(self) -> tuple[float, float]:
        """[rad] slip angles reachable within the steering range."""
        return slip_angle(self.steering_range[0]), slip_angle(self.steering_range[1])

    @classmethod
    def from_env(cls, env: Any, policy_frequency: float | None = None) -> BicycleModel:
        """Read the ego's length, the action ranges and the timing from ``env.unwrapped``; ``policy_frequency`` [Hz]:
        how often the car is commanded, where that is not the env's own (a caller deciding within the env's period)."""
        sim = env.unwrapped
        action_type = sim.action_type
        if type(action_type).__name__ != "ContinuousAction" or not (action_type.longitudinal and action_type.lateral):
            raise ControlError(
                f"the env must use ContinuousAction with longitudinal and lateral control, got {type(action_type).__name__}"
                + (" with steering only (lane-keeping-v0's and the racetracks' own action): make the env with "
                   "config={'action': {'type': 'ContinuousAction'}}"
                   if type(action_type).__name__ == "ContinuousAction" else "")
            )
        if getattr(action_type, "dynamical", False):
            raise ControlError("ContinuousAction(dynamical=True) uses BicycleVehicle, not the kinematic model inverted here")
        sim_hz = sim.config["simulation_frequency"]
        policy_hz = sim.config["policy_frequency"] if policy_frequency is None else policy_frequency
        check_frequencies(sim_hz, policy_hz)
        return cls(
            length=float(sim.vehicle.LENGTH),
            acceleration_range=tuple(action_type.acceleration_range),
            steering_range=tuple(action_type.steering_range),
            simulation_dt=1.0 / sim_hz,
            steps_per_action=int(sim_hz // policy_hz),
        )


def check_frequencies(simulation_hz: Any, policy_hz: Any) -> None:
    """ControlError naming both frequencies unless each is a finite number > 0 [Hz] and the simulation frequency is
    at least the policy frequency: each action is held for ``simulation // policy`` simulation steps, which must be
    at least one."""
    for name, value in (("simulation_frequency", simulation_hz), ("policy_frequency", policy_hz)):
        if not (isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value) and value > 0):
            raise ControlError(f"the env's {name} must be a finite number > 0 Hz, got {value!r} (simulation_frequency "
                               f"{simulation_hz!r} Hz, policy_frequency {policy_hz!r} Hz)")
    if simulation_hz // policy_hz < 1:
        raise ControlError(f"the env's policy_frequency ({policy_hz:g} Hz) is above its simulation_frequency "
                           f"({simulation_hz:g} Hz): the simulation frequency must be at least the policy frequency, "
                           "since each action is held for whole simulation steps")


class Command(NamedTuple):
    """One ego command, in physical units and as the normalised action."""

    acceleration: float  # [m/s^2] after clipping to the range
    steering: float  # [rad] front-wheel angle after clipping
    action: np.ndarray  # (2,) float32 in [-1, 1]: what env.step takes
    saturated: bool  # the exact inverse needed more than the ranges allow


def steering_for_slip(beta: float) -> float:
    """[rad] front-wheel angle that gives slip angle ``beta`` (inverse of ``slip_angle``): arctan(2 tan(beta))."""
    return math.atan(2.0 * math.tan(beta))


def to_action(acceleration: float, steering: float, model: BicycleModel) -> np.ndarray:
    """(2,) float32 ContinuousAction in [-1, 1] for physical (acceleration [m/s^2], steering [rad]): inverse of upstream's lmap."""
    (a_lo, a_hi), (s_lo, s_hi) = model.acceleration_range, model.steering_range
    action = np.array([-1.0 + 2.0 * (acceleration - a_lo) / (a_hi - a_lo), -1.0 + 2.0 * (steering - s_lo) / (s_hi - s_lo)])
    return np.clip(action, -1.0, 1.0).astype(np.float32)


def from_action(action: np.ndarray, model: BicycleModel) -> tuple[float, float]:
    """Physical (acceleration [m/s^2], steering [rad]) of a normalised action, as upstream maps it."""
    u = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
    (a_lo, a_hi), (s_lo, s_hi) = model.acceleration_range, model.steering_range
    return float(a_lo + (u[0] + 1.0) * (a_hi - a_lo) / 2.0), float(s_lo + (u[1] + 1.0) * (s_hi - s_lo) / 2.0)


class EgoKinematics(NamedTuple):
    """What the inverse needs of the ego now."""

    speed: float  # [m/s]
    heading: float  # [rad] body heading (not the course) in the trajectory's axes: world axes for world plans


def ego_kinematics(env: Any) -> EgoKinematics:
    """Speed and world body heading of ``env.unwrapped.vehicle`` (the axes of :mod:`driveopt.sim.world_plan`; on a
    road along +x, the road frame's)."""
    vehicle = env.unwrapped.vehicle
    return EgoKinematics(speed=float(vehicle.speed), heading=wrap_angle(float(vehicle.heading)))


def predict(state: EgoKinematics, acceleration: float, steering: float, model: BicycleModel) -> tuple[np.ndarray, EgoKinematics]:
    """Upstream's integration over one action period from the origin: (displacement (2,) [m], state after)."""
    beta = slip_angle(steering)
    p = np.zeros(2)
    v, psi = state.speed, state.heading
    for _ in range(model.steps_per_action):
        p += v * np.array([math.cos(psi + beta), math.sin(psi + beta)]) * model.simulation_dt
        psi += v * math.sin(beta) / (0.5 * model.length) * model.simulation_dt
        v += acceleration * model.simulation_dt
    return p, EgoKinematics(speed=v, heading=psi)


class TrajectorySample(NamedTuple):
    """A trajectory read between its nodes (each field shaped like the query times)."""

    x: np.ndarray  # [m]
    y: np.ndarray  # [m]
    vx: np.ndarray  # [m/s]
    vy: np.ndarray  # [m/s]


def _hermite(t: np.ndarray, f: np.ndarray, df: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Cubic Hermite interpolation of f with derivative df on nodes t; clamped to the end values outside."""
    q = np.clip(query, t[0], t[-1])
    i = np.clip(np.searchsorted(t, q, side="right") - 1, 0, t.size - 2)
    h = t[i + 1] - t[i]
    s = (q - t[i]) / h
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * f[i] + h10 * h * df[i] + h01 * f[i + 1] + h11 * h * df[i + 1]


def sample_trajectory(trajectory: Trajectory, times: Any) -> TrajectorySample:
    """Positions and velocities at ``times`` [s] (trajectory time, t = 0 at planning), third-order accurate.

    Positions interpolate (x, vx) and velocities (vx, ax) with cubic Hermite polynomials, so reading a
    plan between its nodes (0.15 s apart by default) adds no visible error; clamped outside [t_0, t_K].
    """
    fields = ("t", "x", "y", "vx", "vy", "ax", "ay")
    t, x, y, vx, vy, ax, ay = (np.asarray(getattr(trajectory, f), dtype=float) for f in fields)
    if t.ndim != 1 or t.size < 2 or any(a.shape != t.shape for a in (x, y, vx, vy, ax, ay)):
        raise ControlError(f"need one trajectory with 1-D node arrays of equal length, got t {t.shape}, x {x.shape}")
    if not all(np.all(np.isfinite(a)) for a in (t, x, y, vx, vy, ax, ay)):
        raise ControlError("trajectory contains NaN or inf")
    if np.any(np.diff(t) <= 0):
        raise ControlError("trajectory times must increase")
    q = np.asarray(times, dtype=float)
    return TrajectorySample(
        x=_hermite(t, x, vx, q), y=_hermite(t, y, vy, q), vx=_hermite(t, vx, ax, q), vy=_hermite(t, vy, ay, q)
    )


def track(trajectory: Trajectory, elapsed: float, state: EgoKinematics, model: BicycleModel) -> Command:
    """The command for the action period starting ``elapsed`` [s] after the trajectory's t = 0."""
    if not (math.isfinite(elapsed) and math.isfinite(state.speed) and math.isfinite(state.heading)):
        raise ControlError(f"elapsed time and ego state must be finite, got {elapsed}, {state}")
    h, n = model.simulation_dt, model.steps_per_action
    period = model.action_period

    mid = elapsed + h * (np.arange(n) + 0.5)  # midpoints of the period's simulation steps [s]
    plan = sample_trajectory(trajectory, np.append(mid, elapsed + period))
    a_exact = (math.hypot(plan.vx[-1], plan.vy[-1]) - state.speed) / period
    a_lo, a_hi = model.acceleration_range
    acceleration = min(max(a_exact, a_lo), a_hi)

    course = np.arctan2(plan.vy, plan.vx)  # planned course over each step and at the period's end [rad]
    course = state.heading + (course - state.heading + math.pi) % (2.0 * math.pi) - math.pi  # no wrap-around jumps
    v = state.speed + acceleration * h * np.arange(n)  # speed at the start of each step [m/s]
    travelled = np.concatenate([[0.0], np.cumsum(v)[:-1]]) * h  # [m] path length before each step
    weights = np.maximum(v, 0.0) + 1e-9
    gain = 1.0 / (0.5 * model.length)

    def mismatch(beta: float) -> float:
        """Speed-weighted mean (model course - planned course) over the steps, or with one step (model course after
        it - planned course at its end); increasing in beta for v >= 0."""
        if n == 1:
            return float(state.heading + gain * math.sin(beta) * state.speed * h + beta - course[-1])
        psi = state.heading + gain * math.sin(beta) * travelled
        return float(np.sum(weights * (psi + beta - course[:-1])))

    lo, hi = model.slip_range
    steer_saturated = mismatch(lo) > 0.0 or mismatch(hi) < 0.0
    if mismatch(lo) >= 0.0:
        beta = lo
    elif mismatch(hi) <= 0.0:
        beta = hi
    else:
        for _ in range(_BISECTION_STEPS):
            beta = 0.5 * (lo + hi)
            if mismatch(beta) > 0.0:
                hi = beta
            else:
                lo = beta
        beta = 0.5 * (lo + hi)
    steering = steering_for_slip(beta)
    s_lo, s_hi = model.steering_range
    steering = min(max(steering, s_lo), s_hi)  # only rounding can take it outside here
    saturated = a_exact != acceleration or steer_saturated
    return Command(acceleration, steering, to_action(acceleration, steering, model), bool(saturated))


def brake_at_least(command: Command, deceleration: float, model: BicycleModel, speed: float) -> Command:
    """``command`` with its acceleration lowered to ``-deceleration`` [m/s^2] when it brakes less.

    A stopping plan is a polynomial whose acceleration starts at the current one and ramps down
    over about a second; a fallback means "brake now", so its braking is applied at once. Never
    brakes below standstill within one action period (``speed`` [m/s]).
    """
    a_lo, a_hi = model.acceleration_range
    target = max(-deceleration, -speed / model.action_period, a_lo)
    if command.acceleration <= target:
        return command
    return Command(target, command.steering, to_action(target, command.steering, model), command.saturated)


def command_from_env(env: Any, trajectory: Trajectory, elapsed: float, model: BicycleModel | None = None) -> Command:
    """The command that follows ``trajectory`` (world coordinates, planned ``elapsed`` [s] ago) from the env's current
    ego state."""
    return track(trajectory, elapsed, ego_kinematics(env), model or BicycleModel.from_env(env))
