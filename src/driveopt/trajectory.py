"""A trajectory read out of its Bernstein coefficients at the time nodes: positions, velocities, accelerations,
speed, heading, curvature. The planner's costs, the fallback, the tracking controller and the plots all read this."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from driveopt.qp import TrajectoryModel, split


class Trajectory(NamedTuple):
    """Trajectory read-out at the nodes; every field (..., K)."""

    t: jnp.ndarray  # [s]
    x: jnp.ndarray  # [m]
    y: jnp.ndarray  # [m]
    vx: jnp.ndarray  # [m/s]
    vy: jnp.ndarray  # [m/s]
    ax: jnp.ndarray  # [m/s^2]
    ay: jnp.ndarray  # [m/s^2]
    speed: jnp.ndarray  # [m/s]
    heading: jnp.ndarray  # [rad] relative to the road direction
    curvature: jnp.ndarray  # [1/m] signed path curvature
    acceleration: jnp.ndarray  # [m/s^2] tangential (along the path)


def evaluate(model: TrajectoryModel, coeffs: jnp.ndarray) -> Trajectory:
    """Positions, velocities, accelerations, heading and curvature of coefficients (..., 2n)."""
    c_x, c_y = split(coeffs)
    x, vx, ax = c_x @ model.W.T, c_x @ model.Wd.T, c_x @ model.Wdd.T
    y, vy, ay = c_y @ model.W.T, c_y @ model.Wd.T, c_y @ model.Wdd.T
    speed = jnp.sqrt(vx * vx + vy * vy)
    safe_speed = jnp.maximum(speed, 1e-3)
    curvature = (vx * ay - vy * ax) / safe_speed**3
    heading = jnp.arctan2(vy, jnp.where(speed < 1e-3, 1.0, vx))
    acceleration = (vx * ax + vy * ay) / safe_speed
    t = jnp.broadcast_to(model.t, x.shape)
    return Trajectory(t, x, y, vx, vy, ax, ay, speed, heading, curvature, acceleration)
