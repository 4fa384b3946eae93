"""Road (Frenet) frame of highway-env's straight roads, and vehicle motion expressed in it.

The driving lanes at a longitudinal position are the straight, non-forbidden lanes that point
along +x and cover that position (highway-v0: all lanes; two-way-v0: the two a->b lanes, not
the oncoming b->a one; merge-v0: the two main lanes, not the on-ramp). Lane i is centred at
``first_lane_center + i * lane_width`` (highway-v0: 4 m wide, centred at y = 0, 4, 8, ...).

Positions come from the lowest driving lane's ``local_coordinates`` (longitudinal,
lateral), shifted by that lane's start, so ``x`` is the distance along the road and ``y``
the lateral offset, both in the same sense as highway-env's world axes (``y`` grows
downwards on screen).

Upstream's kinematic bicycle (``Vehicle.step``) moves the centre along ``heading + beta``
with ``beta = arctan(tan(steering) / 2)``, not along ``heading``; ``Vehicle.velocity`` ignores
``beta`` (an upstream TODO). :func:`vehicle_motion` uses the course ``heading + beta`` and the
acceleration the vehicle is currently applying (``vehicle.action``, held until its next action):
tangential ``a`` and normal ``speed * heading_rate = speed**2 * sin(beta) / (length / 2)``.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from highway_env.road.lane import SineLane, StraightLane

from driveopt.errors import DriveoptError
from driveopt.scene import Road

_ALIGNED = 1e-6  # [-] tolerance on a lane direction being (1, 0)
_GEOMETRY_TOL = 1e-6  # [m] tolerance on equal lane widths and even spacing


class RoadFrameError(DriveoptError):
    """The simulator's road is not a set of straight, parallel, evenly spaced lanes along +x."""


class Motion(NamedTuple):
    """State of a vehicle (or static object) in the road frame."""

    x: float  # [m] along the road
    y: float  # [m] across the road
    vx: float  # [m/s] velocity of the centre
    vy: float  # [m/s]
    ax: float  # [m/s^2] acceleration of the centre
    ay: float  # [m/s^2]
    speed: float  # [m/s] upstream's ``speed`` (signed, along the course)
    heading: float  # [rad] body heading relative to the road, in [-pi, pi)
    course: float  # [rad] direction of motion of the centre relative to the road: heading + slip
    length: float  # [m]
    width: float  # [m]


def wrap_angle(angle: float) -> float:
    """[rad] angle wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def slip_angle(steering: float) -> float:
    """[rad] upstream's slip angle of the centre for a front-wheel angle [rad]: arctan(tan(steering) / 2)."""
    return math.atan(0.5 * math.tan(steering))


def _is_driving_lane(lane: Any) -> bool:
    if not isinstance(lane, StraightLane) or isinstance(lane, SineLane) or lane.forbidden:
        return False
    return abs(lane.direction[0] - 1.0) < _ALIGNED and abs(lane.direction[1]) < _ALIGNED


def driving_lanes(network: Any, x: float) -> list[StraightLane]:
    """The driving lanes of the road section containing world x [m] (nearest section past the ends), lowest y first."""
    sections: list[list[StraightLane]] = []
    for tos in network.graph.values():
        for lanes in tos.values():
            straight = [lane for lane in lanes if _is_driving_lane(lane)]
            if straight:
                sections.append(straight)
    if not sections:
        raise RoadFrameError("the road has no straight, non-forbidden lane along +x")

    def distance(section: list[StraightLane]) -> float:
        start, end = section[0].start[0], section[0].end[0]
        return max(start - x, 0.0, x - end)

    best = min(sections, key=distance)
    return sorted(best, key=lambda lane: lane.start[1])


def road_geometry(lanes: list[StraightLane]) -> Road:
    """Planner :class:`Road` of a section of driving lanes: count, width, centre of the lowest lane."""
    centers = np.array([lane.start[1] for lane in lanes], dtype=float)
    widths = np.array([lane.width_at(0.0) for lane in lanes], dtype=float)
    if np.ptp(widths) > _GEOMETRY_TOL:
        raise RoadFrameError(f"driving lanes have different widths {widths.tolist()} [m]")
    if len(lanes) > 1 and np.max(np.abs(np.diff(centers) - widths[0])) > _GEOMETRY_TOL:
        raise RoadFrameError(f"driving lanes centred at {centers.tolist()} are not adjacent {widths[0]} m lanes")
    return Road(num_lanes=len(lanes), lane_width=float(widths[0]), first_lane_center=float(centers[0]), curvature=0.0)


def to_road_frame(reference: StraightLane, position: np.ndarray) -> tuple[float, float]:
    """[m] (x, y) in the road frame of a world position, through the reference lane's local coordinates."""
    longitudinal, lateral = reference.local_coordinates(np.asarray(position, dtype=float))
    return float(reference.start[0] + longitudinal), float(reference.start[1] + lateral)


def vehicle_motion(obj: Any, reference: StraightLane) -> Motion:
    """Road-frame state of a highway-env vehicle or road object (objects without ``action`` are unaccelerated)."""
    x, y = to_road_frame(reference, obj.position)
    heading = wrap_angle(float(obj.heading) - reference.heading_at(x - reference.start[0]))
    speed = float(obj.speed)
    length, width = float(obj.LENGTH), float(obj.WIDTH)
    action = getattr(obj, "action", None)
    if isinstance(action, dict):
        beta = slip_angle(float(action.get("steering", 0.0)))
        a_t = float(action.get("acceleration", 0.0))
        a_n = speed * speed * math.sin(beta) / (0.5 * length)
    else:
        beta, a_t, a_n = 0.0, 0.0, 0.0
    course = wrap_angle(heading + beta)
    c, s = math.cos(course), math.sin(course)
    return Motion(
        x=x, y=y, vx=speed * c, vy=speed * s, ax=a_t * c - a_n * s, ay=a_t * s + a_n * c,
        speed=speed, heading=heading, course=course, length=length, width=width,
    )
