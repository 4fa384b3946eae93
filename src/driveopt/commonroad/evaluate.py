"""The one judge of every CommonRoad run, driveopt's and FISS's alike: the drivability checker's collision check
against the scenario's obstacles at each time step and its road-boundary check, and the planning problem's own goal
check, on the ego's executed states.

A run ends at its first event: ``collision`` (the ego's box meets an obstacle's), ``collision_while_stopped`` (the
same, the ego at most :data:`STOPPED_SPEED`: recorded traffic, which does not react to the ego, ran into it),
``off_road`` (the box meets the road boundary) or ``goal`` (``PlanningProblem.goal.is_reached``); a run without one
is a ``timeout``.
"""

from __future__ import annotations

from typing import Any, NamedTuple

STOPPED_SPEED = 0.5  # [m/s] a collision at or below this ego speed is counted as recorded traffic running into it


class EgoPose(NamedTuple):
    """The ego's executed state at one time step (world frame)."""

    step: int
    x: float  # [m]
    y: float  # [m]
    yaw: float  # [rad]
    speed: float  # [m/s]
    acceleration: float  # [m/s^2]


class Evaluator:
    """Checks :class:`EgoPose` s of one scenario (see the module docstring)."""

    def __init__(self, scenario: Any, problem: Any, length: float, width: float) -> None:
        from commonroad_dc.boundary.boundary import create_road_boundary_obstacle
        from commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch import create_collision_checker

        self.problem = problem
        self.half_length, self.half_width = 0.5 * length, 0.5 * width
        self.checker = create_collision_checker(scenario)
        _, self.boundary = create_road_boundary_obstacle(scenario, method="obb_rectangles")

    def event(self, pose: EgoPose) -> str | None:
        """The event at ``pose`` (``collision``, ``collision_while_stopped``, ``off_road``, ``goal``) or None."""
        import commonroad_dc.pycrcc as pycrcc
        import numpy as np
        from commonroad.scenario.state import CustomState

        box = pycrcc.RectOBB(self.half_length, self.half_width, pose.yaw, pose.x, pose.y)
        if self.checker.time_slice(pose.step).collide(box):
            return "collision_while_stopped" if pose.speed <= STOPPED_SPEED else "collision"
        if self.boundary.collide(box):
            return "off_road"
        state = CustomState(time_step=pose.step, position=np.array([pose.x, pose.y]), orientation=pose.yaw,
                            velocity=pose.speed, acceleration=pose.acceleration)
        if self.problem.goal.is_reached(state):
            return "goal"
        return None

    def judge(self, poses: list[EgoPose]) -> tuple[str, int | None]:
        """(status, step of the event or None): the first event over ``poses`` after the first (the initial state)."""
        for pose in poses[1:]:
            found = self.event(pose)
            if found is not None:
                return ("success" if found == "goal" else found), pose.step
        return "timeout", None
