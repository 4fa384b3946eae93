"""A route's lanes at a split as a :class:`~driveopt.goal.Goal`: be in a lane that continues the route by the split.

Where the route leaves a road by only some of its lanes (exit-v0's exit leaves road ``("1", "2")`` by its
rightmost-added lane alone; going straight on, that lane ends), the lanes of that road whose end joins a lane of
the route's next road (:data:`driveopt.sim.lane_graph.JOIN_DISTANCE`; where the next road starts offset from all of
them, as a roundabout's exit beside the ring, the nearest) are the ones the car must be in when it reaches the split.
:func:`find_split` reads them from the lane graph, in the frame's coordinates, for the first such split ahead of the
ego; :func:`split_goal` makes them a goal whose band widens with the distance still to
go (:attr:`driveopt.goal.Goal.widen`): one lane's width per :attr:`RouteChange.lane_time` seconds of travel, so a
band far ahead accepts every lane from which it can still be reached and the change is planned while the split is
ahead, one lane at a time. The band is required in full from :attr:`RouteChange.settle_time` before the split;
while lanes remain to be changed the desired speed leaves time for each (:attr:`RouteChange.comfortable_lane_time`)
at the speed of the traffic in it (:func:`entry_flows`: a car kept fast past slow lanes met them too late, beside one
of their cars at its speed),
the plans keep a time gap to the cars in the lanes (:attr:`RouteChange.time_gap`: changing lanes through slower
traffic, a cut-in just behind a car that then brakes is what the collision ellipse alone allows), and the planner's
``route`` cost term counts the lanes still to change.

A split that can no longer be made (:func:`missed`: the band is further across than lane changes at
:attr:`RouteChange.fast_lane_time` per lane reach before the split) is given up: the driver follows the road
straight on instead (:func:`driveopt.sim.perception.perceive`), a lane that still leads somewhere, rather than
braking for or swerving into a lane it cannot reach. Without a route (the ego's or the task's) there is no split.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple, Sequence

import numpy as np

from driveopt.goal import Goal
from driveopt.scene import Neighbour
from driveopt.sim.lane_graph import BRANCH_DISTANCE, JOIN_DISTANCE, driving_lanes, lane_end, lane_start
from driveopt.sim.road_frame import RoadFrame


@dataclass(frozen=True)
class RouteChange:
    """How a route's lane change before a split is paced."""

    lane_time: float = 1.5  # [s] of travel per lane change the band widens by: the latest pace the bounds impose
    min_lane_distance: float = 20.0  # [m] ... and at least this far per lane
    settle_time: float = 1.0  # [s] the route's lanes are required in full from this long before the split
    min_settle_distance: float = 10.0  # [m] ... and at least this far before it
    fast_lane_time: float = 1.0  # [s] per lane: a split further across than this pace reaches is missed
    comfortable_lane_time: float = 1.5  # [s] per lane still to change: the desired speed leaves this long for each
    deceleration: float = 1.5  # [m/s^2] ... and low enough to slow at this rate to each lane's traffic still to enter
    # by where entering it must begin (:func:`entry_flows`, :func:`split_goal`)
    min_speed: float = 8.0  # [m/s] ... but is not lowered below this (5 m/s held exit-v0's car too long beside the
    # traffic of the lanes it had left to cross: 36 of seeds 0-39 arrived against 38 at 8, no collision either way)
    time_gap: float = 0.2  # [s] while lanes remain, the plans keep at least this time gap to the cars in the lanes
    # (the collision ellipses of lane-following cars longer by it at the ego's speed; 0: the controller's own gap;
    # exit-v0 seeds 0-39: 37 arrived at 0.2, 37 at 0.3 but slower, 32 at 0.45, 2 collisions in 20 at 0)

    def __post_init__(self) -> None:
        for name in ("lane_time", "min_lane_distance", "settle_time", "min_settle_distance", "fast_lane_time",
                     "comfortable_lane_time", "deceleration", "min_speed", "time_gap"):
            value = getattr(self, name)
            gap = name == "time_gap"  # [0, 10] s, as EllipseMargin's: 0 is no gap
            number = isinstance(value, (int, float)) and not isinstance(value, bool)
            if not number or not ((0.0 <= value <= 10.0) if gap else (0.0 < value < 1e3)):
                raise ValueError(f"RouteChange.{name} must be a number in {'[0, 10]' if gap else '(0, 1000)'}, got {value!r}")


class Split(NamedTuple):
    """Where the route leaves a road by some of its lanes only, in the frame's coordinates."""

    road: tuple[str, str]  # the road the route leaves by some lanes
    following: tuple[str, str]  # the route's next road
    s: float  # [m] arc length of the split (the road's end)
    bands: tuple[tuple[float, float], ...]  # [m] d ranges of the road's lanes that continue the route (contiguous groups)
    lane_width: float  # [m]


def _joins(lane: Any, following_lanes: list[Any]) -> bool:
    end = lane_end(lane)
    return any(np.linalg.norm(lane_start(nxt) - end) <= JOIN_DISTANCE for nxt in following_lanes)


def _continuing(lanes: list[Any], following_lanes: list[Any]) -> list[bool]:
    """Which of a road's ``lanes`` continue into ``following_lanes``: those joining one (within
    :data:`JOIN_DISTANCE`); where none does, the road's lane whose end lies nearest a following lane's start, if within
    :data:`BRANCH_DISTANCE` (a roundabout's exit starts beside the ring's outer lane, a few metres past its end)."""
    joined = [_joins(lane, following_lanes) for lane in lanes]
    if any(joined):
        return joined
    gaps = [min(float(np.linalg.norm(lane_start(nxt) - lane_end(lane))) for nxt in following_lanes) for lane in lanes]
    nearest = int(np.argmin(gaps))
    return [k == nearest and gaps[k] <= BRANCH_DISTANCE for k in range(len(lanes))]


def find_split(network: Any, frame: RoadFrame, s: float) -> Split | None:
    """The first split of the frame's roads ending ahead of arc length ``s`` [m] (the ego's): a road some, not all,
    of whose driving lanes join the next road the frame follows while another of its lanes joins another road; None
    when the frame has none (always on a road without forks)."""
    roads = frame.roads
    for road, following in zip(roads[:-1], roads[1:]):
        band = next((b for p in frame.pieces for b in p.bands if b.road == road and b.s_to >= s), None)
        if band is None:
            continue
        lanes = driving_lanes(network, road)
        nxt = list(network.graph[following[0]][following[1]])
        joined = _continuing([lane for _, lane in lanes], nxt)
        if all(joined) or not any(joined):
            continue
        others = [list(lanes_) for to, lanes_ in network.graph.get(road[1], {}).items() if (road[1], to) != following]
        if not any(_joins(lane, other) for (_, lane), ok in zip(lanes, joined) if not ok for other in others):
            continue  # the other lanes just end (a lane drop): the road's lane preview leaves them
        groups: list[list[int]] = []
        for k, ok in enumerate(joined):
            if ok:
                if groups and groups[-1][-1] == k - 1:
                    groups[-1].append(k)
                else:
                    groups.append([k])
        half = 0.5 * band.lane_width
        bands = tuple((band.first_center + g[0] * band.lane_width - half, band.first_center + g[-1] * band.lane_width + half)
                      for g in groups)
        return Split(road, following, float(band.s_to), bands, float(band.lane_width))
    return None


def _gap(y: float, bands: tuple[tuple[float, float], ...]) -> float:
    """[m] how far ``y`` lies outside the nearest band (0 inside one)."""
    return min(max(low - y, y - high, 0.0) for low, high in bands)


def lanes_to_change(split: Split, y: float) -> int:
    """How many lane changes still lie between the ego centre ``y`` [m] and the nearest of the split's bands."""
    return math.ceil(_gap(y, split.bands) / split.lane_width - 1e-6)


def settle_distance(speed: float, pace: RouteChange) -> float:
    """[m] how far before the split the route's lanes are required in full, at ``speed`` [m/s]."""
    return max(pace.settle_time * abs(speed), pace.min_settle_distance)


def entry_flows(split: Split, x: float, y: float, neighbours: Sequence[Neighbour]) -> tuple[float | None, ...]:
    """[m/s] for each lane still to enter from the ego centre ``y`` [m], in the order it enters them (the band's own
    last), the mean speed along the road of the cars in it from beside the ego at ``x`` [m] to the split; None for
    a lane with none."""
    lanes = lanes_to_change(split, y)
    low, high = min(split.bands, key=lambda b: _gap(y, (b,)))
    half = 0.5 * split.lane_width
    flows = []
    for k in range(lanes, 0, -1):  # the lane k - 1 lanes short of the band (k = 1: the band's own)
        centre = low + half - (k - 1) * split.lane_width if y < low else high - half + (k - 1) * split.lane_width
        speeds = [max(n.vx, 0.0) for n in neighbours if abs(n.y - centre) < half and x - n.length <= n.x <= split.s]
        flows.append(float(np.mean(speeds)) if speeds else None)
    return tuple(flows)


def split_goal(split: Split, x: float, y: float, speed: float, pace: RouteChange = RouteChange(),
               flows: Sequence[float | None] = ()) -> Goal:
    """The split as a goal for the ego at (``x``, ``y``) [m], ``speed`` [m/s]: its bands, required from
    :func:`settle_distance` before the split, widening by one lane per ``pace.lane_time`` of travel before that
    (the latest pace); never deferred for a slow car in them (the route must be kept). While lanes remain to be
    changed, its speed window leaves ``pace.comfortable_lane_time`` for each of them in the distance to the band's
    start (at least ``pace.min_speed``): a lane change into slower traffic needs time at its speed, not only road.
    With the speeds ``flows`` [m/s] of the traffic in the lanes still to enter (:func:`entry_flows`), the window is also
    no faster than slowing at ``pace.deceleration`` to each lane's speed by the point where entering it must begin
    (each change from there on taking ``pace.comfortable_lane_time`` at the lane's speed, or at ``speed`` in a lane
    without traffic): a car that keeps its speed past slow lanes until the last metres finds itself beside one of
    their cars at its speed."""
    lane_distance = max(pace.lane_time * abs(speed), pace.min_lane_distance)
    start = split.s - settle_distance(speed, pace)
    lanes_left = lanes_to_change(split, y)
    window = None
    if lanes_left > 0:
        fastest = (start - x) / (lanes_left * pace.comfortable_lane_time)
        entry = start  # [m] where entering the lane (from the band's backwards) must begin at the latest
        for flow in reversed(flows):
            entry -= pace.comfortable_lane_time * (abs(speed) if flow is None else flow)
            if flow is not None:
                fastest = min(fastest, math.sqrt(flow * flow + 2.0 * pace.deceleration * max(entry - x, 0.0)))
        window = (0.0, max(fastest, pace.min_speed))
    return Goal(bands=split.bands, x=(start, split.s), speed=window, lead_distance=9999.0, block_speed=9999.0,
                widen=split.lane_width / lane_distance)


def missed(split: Split, x: float, y: float, speed: float, pace: RouteChange = RouteChange()) -> bool:
    """Whether the ego at (``x``, ``y``) [m], ``speed`` [m/s], can no longer reach the split's lanes before the split:
    it lies outside them by more than lane changes at ``pace.fast_lane_time`` per lane cover in the distance left."""
    gap = _gap(y, split.bands)
    if gap <= 0.0:
        return False
    reach = max(split.s - x, 0.0) / max(pace.fast_lane_time * abs(speed), 1e-6) * split.lane_width
    return gap > reach
