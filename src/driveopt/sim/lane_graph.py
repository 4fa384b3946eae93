"""The ego's route through highway-env's lane graph: which road follows which, and the lanes of a road.

highway-env's ``RoadNetwork`` is a graph of nodes joined by roads ``(from, to)``, each road a list of
lanes (``StraightLane``, ``CircularLane``, ``SineLane``). A Frenet frame (:mod:`driveopt.sim.road_frame`)
follows one chain of roads:

- the roads of an explicit route (a list of node names, e.g. ``["0", "1", "2", "exit"]`` to take
  exit-v0's exit), or of the ego's own ``route`` (highway-env's ``ControlledVehicle``) when it has one;
- otherwise, at each node, the road that continues the current one (a lane of it starts where a lane
  of the current road ends, or passes through that end: a road joined part-way along, as lane-keeping-v0's;
  at most :data:`MAX_TURN` away from its heading), non-forbidden roads first,
  then the smallest change of heading (keeping straight on at a fork).

A road's driving lanes are its non-forbidden lanes (all its lanes when every one is forbidden, as on an
exit ramp), ordered from the lowest lateral offset (highway-env's ``y`` on a road along +x) up.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

Road = tuple[str, str]  # (from node, to node)

JOIN_DISTANCE = 1.0  # [m] a lane continues another when it starts within this of the other's end
BRANCH_DISTANCE = 8.0  # [m] a road whose lanes start offset from a road's ends (a roundabout's exit beside the ring,
# a few metres past its end) branches from it when it starts within this of one of them
MAX_TURN = math.radians(60.0)  # [rad] largest change of heading from one road to the next one it continues
U_TURN = math.radians(150.0)  # [rad] a road joined at a larger change of heading runs the other way (an oncoming lane)


def wrap_angle(angle: float) -> float:
    """[rad] angle wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def lane_end(lane: Any) -> np.ndarray:
    """[m] world position of a lane's centre line at its end."""
    return np.asarray(lane.position(lane.length, 0.0), dtype=float)


def lane_start(lane: Any) -> np.ndarray:
    """[m] world position of a lane's centre line at its start."""
    return np.asarray(lane.position(0.0, 0.0), dtype=float)


def driving_lanes(network: Any, road: Road) -> list[tuple[int, Any]]:
    """(lane id, lane) of a road's driving lanes (non-forbidden, or all when all are forbidden), lowest first.

    Lanes are ordered by the lateral offset of their start in the first lane's frame (upstream's lateral
    axis points to the left of the direction of travel: +y on a road along +x)."""
    lanes = list(enumerate(network.graph[road[0]][road[1]]))
    allowed = [(i, lane) for i, lane in lanes if not lane.forbidden] or lanes
    first = allowed[0][1]
    return sorted(allowed, key=lambda item: first.local_coordinates(lane_start(item[1]))[1])


def road_joins(network: Any, current: Road, following: Road) -> list[tuple[Any, Any, float]]:
    """[(lane of ``current``, lane of ``following`` that continues it, where along that lane [m])]: the lanes of
    ``following`` that start within :data:`JOIN_DISTANCE` of where a lane of ``current`` ends (at 0.0); only when none
    does, the lanes that such an end lies on part-way along, within :data:`JOIN_DISTANCE` of their centre line (a road
    joined part-way along, as lane-keeping-v0's approach road joins its sine road 135 m along it)."""
    pairs = [(lane, nxt) for lane in network.graph[current[0]][current[1]]
             for nxt in network.graph[following[0]][following[1]]]
    starts = [(lane, nxt, 0.0) for lane, nxt in pairs if np.linalg.norm(lane_start(nxt) - lane_end(lane)) <= JOIN_DISTANCE]
    if starts:
        return starts
    part_way = []
    for lane, nxt in pairs:
        longitudinal, lateral = nxt.local_coordinates(lane_end(lane))
        if 0.0 < longitudinal < float(nxt.length) and abs(lateral) <= JOIN_DISTANCE:
            part_way.append((lane, nxt, float(longitudinal)))
    return part_way


def _turn(network: Any, current: Road, following: Road) -> float | None:
    """[rad] smallest |change of heading| from a lane of ``current`` into a lane of ``following`` that continues it
    (:func:`road_joins`); None when no lane of ``following`` continues one of ``current``."""
    turns = [abs(wrap_angle(nxt.heading_at(at) - lane.heading_at(lane.length)))
             for lane, nxt, at in road_joins(network, current, following)]
    return min(turns) if turns else None


def junctions(network: Any, road: Road) -> list[tuple[Road, float | None]]:
    """[(road, |change of heading| [rad], None when its lanes do not start where ``road``'s end)] of the roads leaving
    the end node of ``road`` that do not continue it, other than oncoming roads (turned by :data:`U_TURN` or more): the
    other arms of a junction (an intersection's, a roundabout's)."""
    arms = []
    end_heading = [lane.heading_at(lane.length) for lane in network.graph[road[0]][road[1]]]
    for to in network.graph.get(road[1], {}):
        following = (road[1], to)
        turn = _turn(network, road, following)
        start_heading = network.graph[road[1]][to][0].heading_at(0.0)
        oncoming = min(abs(wrap_angle(start_heading - h)) for h in end_heading) >= U_TURN
        if not oncoming and (turn is None or turn > MAX_TURN):
            arms.append((following, turn))
    return arms


def _continues(network: Any, current: Road, following: Road) -> float | None:
    """[rad] |change of heading| where ``following`` continues ``current`` (one of its lanes starts where one of
    ``current``'s ends), or None when it does not continue it (no joined lanes, a U-turn or a sharp turn)."""
    turn = _turn(network, current, following)
    return turn if turn is not None and turn <= MAX_TURN else None


def continues_past_end(network: Any, road: Road, other_than: Road | None = None) -> bool:
    """Whether another road (not ``other_than``) continues ``road``'s lanes at its end (a ring's segment past an exit:
    yes; an entry: no)."""
    return any(_continues(network, road, (road[1], to)) is not None for to in network.graph.get(road[1], {})
               if (road[1], to) != other_than)


def continued_before_start(network: Any, road: Road, other_than: Road | None = None) -> bool:
    """Whether another road (not ``other_than``) leads into ``road``'s lanes at its start (a ring's segment after an
    entry: yes)."""
    return any(_continues(network, (frm, road[0]), road) is not None for frm, tos in network.graph.items()
               if road[0] in tos and (frm, road[0]) != other_than)


def _all_forbidden(network: Any, road: Road) -> bool:
    return all(lane.forbidden for lane in network.graph[road[0]][road[1]])


def next_road(network: Any, road: Road, route: Sequence[Road] = ()) -> Road | None:
    """The road the frame follows after ``road``: the route's next road when the route continues there,
    else the continuing road (see the module docstring); None at a dead end."""
    successors = [(road[1], to) for to in network.graph.get(road[1], {})]
    planned = [r for r in successors if r in route]
    if planned:
        return planned[0]
    scored = [(_all_forbidden(network, r), turn, r) for r in successors
              if (turn := _continues(network, road, r)) is not None]
    return min(scored)[2] if scored else None


def previous_road(network: Any, road: Road, route: Sequence[Road] = ()) -> Road | None:
    """The road the frame follows before ``road`` (the mirror of :func:`next_road`); None when none continues into it."""
    predecessors = [(frm, road[0]) for frm, tos in network.graph.items() if road[0] in tos]
    planned = [r for r in predecessors if r in route]
    if planned:
        return planned[0]
    scored = [(_all_forbidden(network, r), turn, r) for r in predecessors
              if (turn := _continues(network, r, road)) is not None]
    return min(scored)[2] if scored else None


def route_roads(route: Sequence[Any] | None) -> tuple[Road, ...]:
    """The roads of a route given as node names (``["0", "1", "2", "exit"]``) or as highway-env lane indices
    (``[("0", "1", 0), ...]``, a ``ControlledVehicle.route``); () for None."""
    if not route:
        return ()
    if all(isinstance(node, str) for node in route):
        return tuple(zip(route[:-1], route[1:]))
    return tuple((str(index[0]), str(index[1])) for index in route)


# Where upstream envs send an ego that has no route of its own: with ContinuousAction the ego is a plain Vehicle,
# whose missing ``plan_route_to`` the envs skip. intersection-v0 names the destination in its config; the others
# only in their code: roundabout-v0 routes the ego to node "nxs" (the ring's northern exit), u-turn-v0 to "d" (the
# road back after the U-turn), and exit-v0 counts success on its exit (node "exit").
_CODED_DESTINATIONS = {"RoundaboutEnv": "nxs", "UTurnEnv": "d", "ExitEnv": "exit"}


def env_destination_route(sim: Any) -> tuple[str, ...] | None:
    """The node names from the ego's road to the destination ``sim`` (an unwrapped highway-env env) routes its ego to
    (its config's ``destination``, or the one upstream's code plans for it); None when the ego has a route of its
    own, the env names no destination, or the lane graph has no way there."""
    ego = sim.vehicle
    if getattr(ego, "route", None):
        return None
    coded = next((_CODED_DESTINATIONS[c.__name__] for c in type(sim).__mro__ if c.__name__ in _CODED_DESTINATIONS), None)
    destination = (getattr(sim, "config", None) or {}).get("destination") or coded
    if destination is None:
        return None
    start, end = ego.lane_index[:2]
    path = sim.road.network.shortest_path(end, destination)
    return (start, *path) if path else None
