"""How a closed loop turns the plan it follows into the car's command for one policy period: strategies passed to
:class:`driveopt.drivers.optimiser.ClosedLoop` as ``command``.

- :class:`ExactTracking` (driveopt's): the exact inverse of upstream's bicycle model over the period
  (:func:`driveopt.sim.control.track`), so the car ends the period at the plan's speed and on its course.
- :class:`FirstNodesMean` (P2's authors, ``model/DOptimizerJax3.py`` ``inference``): the mean speed and the mean
  steering angle of the plan's first eight nodes (0.15 s apart), the acceleration that reaches that speed over the
  time to the eighth node, both handed to ``env.step`` as they are, in physical units where ContinuousAction expects
  [-1, 1]: the simulator clips them to [-1, 1] and maps them onto its ranges, so at highway-env's defaults the car
  accelerates at 5 x (v_mean - v) / 1.05 s [m/s^2] (clipped at +-5) and steers at pi/4 x the mean angle [rad].

Both take the plan in world coordinates (``followed``), the time since it was planned, the car's speed and heading,
and the car's model, and return a :class:`~driveopt.sim.control.Command`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from driveopt.sim.control import BicycleModel, Command, EgoKinematics, ControlError, from_action, sample_trajectory, track
from driveopt.trajectory import Trajectory


@dataclasses.dataclass(frozen=True)
class ExactTracking:
    """The command that makes upstream's bicycle model follow the plan over the period (driveopt's)."""

    def __call__(self, followed: Trajectory, elapsed: float, state: EgoKinematics, model: BicycleModel) -> Command:
        return track(followed, elapsed, state, model)


@dataclasses.dataclass(frozen=True)
class FirstNodesMean:
    """P2's authors' command: the means over the plan's first ``nodes`` nodes, passed on unscaled (module docstring)."""

    nodes: int = 8  # [-] DOptimizerJax3.py num_mean_update
    node_spacing: float = 0.15  # [s] their plan's nodes: 100 over 15 s
    wheel_base: float = 2.875  # [m] steering angle = arctan(wheel_base x path curvature)

    def __post_init__(self) -> None:
        if not (isinstance(self.nodes, int) and self.nodes >= 2 and self.node_spacing > 0 and self.wheel_base > 0):
            raise ControlError("FirstNodesMean needs nodes >= 2 and a positive node_spacing [s] and wheel_base [m]")

    @property
    def target_time(self) -> float:
        """[s] from the first node to the last averaged one: the time the speed change is spread over."""
        return (self.nodes - 1) * self.node_spacing

    def __call__(self, followed: Trajectory, elapsed: float, state: EgoKinematics, model: BicycleModel) -> Command:
        if not (math.isfinite(elapsed) and math.isfinite(state.speed)):
            raise ControlError(f"elapsed time and ego speed must be finite, got {elapsed}, {state.speed}")
        times = elapsed + self.node_spacing * np.arange(self.nodes)
        reading = sample_trajectory(followed, times)
        t = np.asarray(followed.t, dtype=float)
        ax = np.interp(times, t, np.asarray(followed.ax, dtype=float))
        ay = np.interp(times, t, np.asarray(followed.ay, dtype=float))
        speed = np.hypot(reading.vx, reading.vy)
        curvature = (reading.vx * ay - reading.vy * ax) / np.maximum(speed, 1e-3) ** 3
        acceleration = (float(np.mean(speed)) - state.speed) / self.target_time  # [m/s^2], passed on as a [-1, 1] value
        steering = float(np.mean(np.arctan(self.wheel_base * curvature)))  # [rad], likewise
        raw = np.array([acceleration, steering])
        action = np.clip(raw, -1.0, 1.0).astype(np.float32)
        physical_acceleration, physical_steering = from_action(action, model)
        return Command(physical_acceleration, physical_steering, action, bool(np.any(np.abs(raw) > 1.0)))


EXACT_TRACKING = ExactTracking()
P2_AUTHORS_COMMAND = FirstNodesMean()
