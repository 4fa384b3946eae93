"""A plan made in the road frame, turned back into world coordinates for tracking and drawing.

A node at arc length ``s`` and offset ``d`` (with rates ``s'``, ``d'``, ``s''``, ``d''``) lies at the world
point of the reference line's lane at ``(s, d)``; with the reference line's heading ``theta``, curvature
``kappa`` and the offset ``n`` from it, the velocity in the line's (tangent, normal) basis is
``(u, w) = ((1 - kappa n) s', d')`` and the acceleration ``(u' - theta' w, w' + theta' u)`` with
``theta' = kappa s'`` and ``u' = (1 - kappa n) s'' - kappa d' s'`` (the change of curvature along the road
is neglected); both are turned by ``theta`` into world axes. On a straight road along +x (``theta = 0``,
``kappa = 0``) the velocities and accelerations are the planned ones, exactly.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from driveopt.sim.road_frame import RoadFrame


class WorldTrajectory(NamedTuple):
    """A trajectory in world coordinates at the plan's nodes (each (N,)); what :func:`driveopt.sim.control.track` reads."""

    t: np.ndarray  # [s] since the plan was made
    x: np.ndarray  # [m] world X
    y: np.ndarray  # [m] world Y
    vx: np.ndarray  # [m/s]
    vy: np.ndarray  # [m/s]
    ax: np.ndarray  # [m/s^2]
    ay: np.ndarray  # [m/s^2]


def to_world(trajectory: Any, frame: RoadFrame) -> WorldTrajectory:
    """``trajectory`` (fields t, x = s, y = d, vx, vy, ax, ay in the frame) in world coordinates."""
    t, s, d, s_dot, d_dot, s_ddot, d_ddot = (np.asarray(getattr(trajectory, f), dtype=float)
                                             for f in ("t", "x", "y", "vx", "vy", "ax", "ay"))
    x, y, theta, kappa, offset = frame.to_world(s, d)
    scale = 1.0 - kappa * offset
    u, w = scale * s_dot, d_dot
    turn_rate = kappa * s_dot
    u_dot = scale * s_ddot - kappa * d_dot * s_dot
    a_t, a_n = u_dot - turn_rate * w, d_ddot + turn_rate * u
    c, sn = np.cos(theta), np.sin(theta)
    return WorldTrajectory(t=t, x=x, y=y, vx=c * u - sn * w, vy=sn * u + c * w, ax=c * a_t - sn * a_n, ay=sn * a_t + c * a_n)
