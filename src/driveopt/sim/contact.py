"""The contact guard: the last check of a command against the cars' boxes, with the simulator's own motion model.

The planner keeps the ego's centre outside ellipses around its neighbours; the simulator collides rotated
rectangles. The two disagree most at crawling speed next to a standing car: a car turned across its lane
moves along its body heading plus the slip of its steering, not along a plan's course, so a plan that slides
sideways away from the car beside it can still push the body's corner into that car (P2 Fig. 7 dense road,
episode 24: standing 6 cm from a stopped car's corner, every replan accelerated for one period and the
fallback braked in the next, 4 cm closer each time, until the corner touched).

:func:`guard` rolls the command out over one action period and then brakes as hard as the car can with the
steering held (the earliest the next decision could stop it), and rolls out braking now, both over the same
time and at least :data:`MIN_HORIZON`; neighbours keep their velocity. Each rollout's clearance is the smallest
separation of the ego's box from a neighbour's along it (:func:`separation`; negative when they overlap). When the command's clearance falls below :data:`CONTACT_MARGIN` and braking now keeps more,
braking now is returned instead. The margin matters: upstream counts a crash when the boxes would touch after
one more simulation step along the bodies' headings, and a car creeping past a corner 2 mm away (P2 Fig. 7
episode 2 at 31.0 s) crashed 0.1 s later.

It acts only at crawling speed (:data:`GUARD_SPEED`): there the planner's course and curvature bounds are off
(below 1 m/s a stopping car's direction means nothing to them), and the rollout is short (0.9 m to stop from
3 m/s) and true to the car. At speed, holding the steering through a long stop is fiction (a lane change's
steering held for 60 m crosses lanes), and the planner's bounds and obstacle rows are what keep the car clear.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from driveopt.scene import Scene
from driveopt.sim.control import BicycleModel, Command, EgoKinematics, to_action
from driveopt.sim.road_frame import slip_angle

GUARD_SPEED = 3.0  # [m/s] the guard checks commands at or below this speed
CONTACT_MARGIN = 0.1  # [m] clearance a command may not take away (2 m/s closing over one 20 Hz simulation step)
CLEARANCE_TOLERANCE = 1e-3  # [m] braking now must keep this much more clearance than the command to replace it
MIN_HORIZON = 1.0  # [s] shortest rollout (standing still after a stop): long enough to see a car closing in
MAX_HORIZON = 10.0  # [s] longest rollout: a stop from 50 m/s at 5 m/s^2


class Boxes(NamedTuple):
    """Rectangles, broadcastable: centres [m], headings [rad] (of the length axis), half-length and half-width [m]."""

    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    half_length: np.ndarray
    half_width: np.ndarray


def separation(a: Boxes, b: Boxes) -> np.ndarray:
    """[m] separation of each pair of rectangles (broadcast over a's and b's arrays): the largest gap between their
    shadows on the four edge normals; positive: apart by at least that much (the distance, when an edge faces the
    other box), zero: touching, negative: overlapping. A rectangle's shadow on a unit axis u has radius
    l |e_l . u| + w |e_w . u|."""
    dx, dy = b.x - a.x, b.y - a.y
    gaps = []
    for heading in (a.heading, a.heading + 0.5 * math.pi, b.heading, b.heading + 0.5 * math.pi):
        ux, uy = np.cos(heading), np.sin(heading)
        radius = sum(half * np.abs(np.cos(h) * ux + np.sin(h) * uy) + other * np.abs(-np.sin(h) * ux + np.cos(h) * uy)
                     for h, half, other in ((a.heading, a.half_length, a.half_width), (b.heading, b.half_length, b.half_width)))
        gaps.append(np.abs(dx * ux + dy * uy) - radius)
    return np.maximum.reduce(np.broadcast_arrays(*gaps))


def rollout(state: EgoKinematics, acceleration: float, steering: float, model: BicycleModel,
            until: float = MIN_HORIZON) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Upstream's integration from the origin: ``acceleration`` [m/s^2] for one action period, then
    the hardest braking until standstill (never reversing), the steering [rad] held throughout; standing still
    until ``until`` [s] when it stops sooner.

    Returns (t, x, y, heading) after each simulation step [s, m, m, rad], (T,) each, the start included."""
    beta = slip_angle(steering)
    a_brake = model.acceleration_range[0]
    h = model.simulation_dt
    px = py = 0.0
    v, psi = max(state.speed, 0.0), state.heading
    out = [(0.0, px, py, psi)]
    steps = model.steps_per_action
    k = 0
    while k * h < MAX_HORIZON and (k < steps or v > 0.0 or (k + 0.5) * h < until):
        a = acceleration if k < steps else a_brake
        px += v * math.cos(psi + beta) * h
        py += v * math.sin(psi + beta) * h
        psi += v * math.sin(beta) / (0.5 * model.length) * h
        v = max(v + a * h, 0.0)
        k += 1
        out.append((k * h, px, py, psi))
    return tuple(np.asarray(col) for col in zip(*out))


def clearance(t: np.ndarray, x: np.ndarray, y: np.ndarray, heading: np.ndarray, scene: Scene) -> float:
    """[m] smallest :func:`separation` of the ego's box, at (x, y) relative to its position now with ``heading``
    at times ``t``, from the neighbours of ``scene``, which keep their velocity (inf: no neighbour)."""
    if not scene.neighbours:
        return math.inf
    ego = scene.ego
    n = scene.neighbours
    nx = np.array([o.x - ego.x for o in n])[None, :] + np.array([o.vx for o in n])[None, :] * t[:, None]
    ny = np.array([o.y - ego.y for o in n])[None, :] + np.array([o.vy for o in n])[None, :] * t[:, None]
    others = Boxes(nx, ny, np.array([o.heading for o in n])[None, :],
                   0.5 * np.array([o.length for o in n])[None, :], 0.5 * np.array([o.width for o in n])[None, :])
    me = Boxes(x[:, None], y[:, None], heading[:, None], 0.5 * ego.length, 0.5 * ego.width)
    return float(np.min(separation(me, others)))


def guard(command: Command, state: EgoKinematics, scene: Scene, model: BicycleModel) -> tuple[Command, bool]:
    """(``command``, False), or (braking now, True) when ``command``'s rollout comes within :data:`CONTACT_MARGIN`
    of a neighbour and braking now keeps more clearance, at or below :data:`GUARD_SPEED` (see the module docstring).
    Braking now never reverses within one action period."""
    if state.speed > GUARD_SPEED:
        return command, False
    a_brake = max(model.acceleration_range[0], -max(state.speed, 0.0) / model.action_period)
    if command.acceleration <= a_brake:
        return command, False
    moving = rollout(state, command.acceleration, command.steering, model)
    closest = clearance(*moving, scene)
    if closest >= CONTACT_MARGIN:
        return command, False
    if clearance(*rollout(state, a_brake, command.steering, model, until=moving[0][-1]), scene) <= closest + CLEARANCE_TOLERANCE:
        return command, False
    return Command(a_brake, command.steering, to_action(a_brake, command.steering, model), command.saturated), True
