"""From the simulator to the planner: the current state as a :class:`~driveopt.scene.Scene`, read once per step.

:func:`perceive` reads ``env.unwrapped`` once: the Frenet frame along the ego's route (see
:mod:`driveopt.sim.road_frame`; any road of straight, circular and sine lanes), the ego in it, the lanes
that continue ahead, the road's curvature ahead (for the centripetal bound), and every other vehicle
and collidable road object the frame reaches, with its actual length and width. It returns the planning
scene, the frame, and the ego's speed and body heading for the controller (relative to the road for the
contact guard, in world axes for :func:`driveopt.sim.control.track`, which follows plans turned into world
coordinates by :mod:`driveopt.sim.world_plan`).

The sharpest curvature within the preview's :attr:`RoadPreview.curvature_distance` or
:attr:`RoadPreview.curvature_time` bounds the plan (or, with :attr:`RoadPreview.curvature_per_node`, each node there
by the curvature where it is: a table of cells, :meth:`RoadFrame.curvature_cells`). Curves ahead lower the scene's
desired speed to the fastest from which the car can still slow to a curve's speed
(``sqrt(lateral_acceleration / |kappa|)``) at :attr:`RoadPreview.deceleration`: with one curvature for the whole
plan, a car would otherwise meet the bound only when the curve entered the preview, too fast. On a straight road the
desired speed, the road and every state are the straight road's, exactly.

A route (the task's, or the ego's own) that leaves a road by only some of its lanes is a
:class:`~driveopt.goal.Goal` (:mod:`driveopt.sim.route_goal`): the lanes that continue the route, required by the
split and widening with the distance still to go, so the lane change is planned while the split is ahead. Until
the split the road keeps the lanes that go elsewhere (the goal, not the lane preview, leads out of them). A split
the car can no longer make is given up: the scene is then read along the road straight on, without the route; so
is one it has just passed outside the route's lanes (the route's road still holds the car a few metres past its end,
and its frame leads on in the route's lanes alone).

A vehicle on a road the frame does not follow whose own lanes cross the route's (:mod:`driveopt.sim.crossing`)
is predicted along them and mapped onto the frame node by node (a
:class:`~driveopt.prediction.PathNeighbour`); every other vehicle as before.

The ego's velocity in the scene points along its course (body heading + the slip angle of the
steering applied now), as the simulator integrates it, so a plan starts with the lateral velocity
the car has; the plans leave their lateral acceleration free (``qp.initial_lateral_acceleration``)
because the slip angle is a command that can jump every period. With the velocity along the body
heading instead, the lateral motion of the last command was forgotten at every replan and the car
followed only the slow start of each plan (sideways at about a quarter of the planned
rate, and slow drifts across lanes).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from typing import Any, NamedTuple, Sequence

from driveopt.config import ProjectionConfig
from driveopt.goal import Goal
from driveopt.observation import ObservationError
from driveopt.scene import CURVATURE_CELL, PATH_SCALE_MIN, EgoState, EllipseMargin, Neighbour, ProblemError, Scene
from driveopt.sim.control import EgoKinematics
from driveopt.sim.crossing import crossing_neighbour, lane_leaving_neighbour, may_cross, wreck_neighbour
from driveopt.sim.lane_graph import BRANCH_DISTANCE, route_roads
from driveopt.sim.road_frame import Motion, RoadFrame, ego_frame, vehicle_motion, wrap_angle
from driveopt.sim.route_goal import (RouteChange, entry_flows, find_split, lanes_to_change, missed, settle_distance,
                                     split_goal)


@dataclass(frozen=True)
class RoadPreview:
    """How far along the route the scene looks, and the speed advice for curves."""

    lateral_acceleration: float = ProjectionConfig.centripetal_max  # [m/s^2] the planner's centripetal bound
    deceleration: float = 1.5  # [m/s^2] comfortable braking towards a curve's speed
    lane_time: float = 4.0  # [s] lanes ending within this time at the current speed are left out of the road
    lane_distance: float = 30.0  # [m] ... or within this distance, whichever is further
    lane_gap_time: float = 2.0  # [s] a road whose lanes leave a gap between them (RoadFrame.road), starting within this
    # time at the current speed, holds the car in the lane nearest it until that road ends (a change under way then
    # ends there); before, the car may change lanes (held from the whole lane preview, it followed slower cars)
    lane_gap_distance: float = 10.0  # [m] ... or within this distance, whichever is further
    curvature_time: float = 1.5  # [s] the curvature within this time ahead enters the centripetal bound
    curvature_distance: float = 10.0  # [m] ... or within this distance, whichever is further
    # False: the sharpest curvature within that preview bounds every node of the plan; True: each node within it is
    # bounded by the curvature where the node is (none beyond). Measured on upstream's curved envs (docs/controller.md):
    # 1-14 % faster, but 6 collisions in 180 episodes against 3, at ring entries: off.
    curvature_per_node: bool = False
    speed_distance: float = 300.0  # [m] curves within this distance lower the desired speed
    slowing: float = 0.0  # [m/s^2] the scene's slowing where no curve lowers the desired speed (a driver lets a car
    # faster than it slow at this rate: Scene.slowing_from), else 0: faster than a curve's speed, brake at once
    route_change: RouteChange = RouteChange()  # the pace of a route's lane change before a split
    target_lanes: bool = True  # each car's lateral motion is predicted to end at the centre of the lane it steers to
    # (highway-env's target lane; Neighbour.lane_center); False: at its lateral rate for the whole horizon (P1)
    crossing_horizon: float = 15.0  # [s] crossing traffic is predicted along its lanes this far ahead
    crossing_step: float = 0.5  # [s] ... at poses this far apart
    dead_end_time: float = 8.0  # [s] a dead end (a road with no road after it) on the route's destination road or
    # past it, within this time at the current speed, stands as a wall across its lanes (:func:`dead_end_walls`)
    dead_end_distance: float = 30.0  # [m] ... or within this distance, whichever is further

    def __post_init__(self) -> None:
        for name in ("lateral_acceleration", "deceleration", "lane_time", "lane_distance", "lane_gap_time",
                     "lane_gap_distance", "curvature_time", "curvature_distance", "speed_distance", "slowing",
                     "crossing_horizon", "crossing_step", "dead_end_time", "dead_end_distance"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= float(value) < 1e4:
                raise ValueError(f"RoadPreview.{name} must be a number in [0, 10000), got {value!r}")
        for name in ("lateral_acceleration", "deceleration", "crossing_step"):
            if getattr(self, name) == 0:
                raise ValueError(f"RoadPreview.{name} must be > 0")
        for name in ("curvature_per_node", "target_lanes"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"RoadPreview.{name} must be True or False, got {getattr(self, name)!r}")


class Perception(NamedTuple):
    """What one closed-loop step knows of the world."""

    scene: Scene  # planning scene in the road frame: the ego's velocity along its course
    kinematics: EgoKinematics  # the ego's speed [m/s] and body heading relative to the road [rad] (contact guard)
    frame: RoadFrame | None = None  # the Frenet frame the scene is in
    tracking: EgoKinematics | None = None  # the ego's speed [m/s] and world body heading [rad] (tracking world plans)
    goal: Goal | None = None  # the route's lanes at the split ahead (build_problem's goal=); None without one


def curve_speed(frame: RoadFrame, s: float, d: float, v_des: float, preview: RoadPreview, period: float = 0.0) -> float:
    """[m/s] the rate along the frame's reference line (the planner's speed) at which a car at ``s`` [m] and ``d`` [m]
    drives at ``v_des`` (beside a line of curvature ``kappa`` at ``d0`` the car moves ``1 - kappa (d - d0)`` times as
    fast as its rate), lowered to the fastest rate from which the car slows to each curve's within
    ``preview.speed_distance`` ahead at ``preview.deceleration``, having first driven one ``period`` [s] at ``v_des``
    (the next decision comes a policy period later: at 1 Hz that is 10 m at 10 m/s). A curve's rate is the lower of
    the centripetal bound's (the car's lateral acceleration, ``rate^2 |kappa| (1 - kappa (d - d0))``, at
    ``preview.lateral_acceleration``) and ``v_des``'s there. The car slows to the first by the point where the curve
    enters the centripetal bound: with the preview's sharpest curvature bounding a whole plan, when the curve comes
    within ``curvature_distance`` or ``curvature_time`` at the curve's rate (else the bound is violated from the
    plan's first node and the call is infeasible); with ``curvature_per_node`` the plan can brake within the
    preview, and it is the curve itself (less one cell of the planner's curvature table, whose cells read their
    neighbours too). It slows to ``v_des``'s rate at the curve itself."""
    def scale(kappa: float, origin: float) -> float:
        return max(1.0 - kappa * (d - origin), PATH_SCALE_MIN)

    rate = v_des / scale(*frame.curve_at(s))
    for distance, kappa, origin in frame.curves_ahead(s, s + preview.speed_distance):
        if kappa != 0.0:
            v_curve = math.sqrt(preview.lateral_acceleration / (abs(kappa) * scale(kappa, origin)))
            margin = (CURVATURE_CELL if preview.curvature_per_node
                      else max(preview.curvature_distance, preview.curvature_time * v_curve))
            for target, before in ((v_curve, margin), (v_des / scale(kappa, origin), 0.0)):
                slowing = max(distance - before - v_des * period, 0.0)
                rate = min(rate, math.sqrt(target * target + 2.0 * preview.deceleration * slowing))
    return rate


DEAD_END_WALL = 1.0  # [m] length of each lane's standing box just beyond a dead end


def dead_end_walls(frame: RoadFrame, s: float, speed: float, preview: RoadPreview,
                   destination: tuple[str, str] | None) -> list[Neighbour]:
    """A standing box across each lane of a dead end (:attr:`RoadFrame.dead_end`) on the route's ``destination`` road
    or past it, within the preview's reach of ``s`` [m] at ``speed`` [m/s], its rear on the road's end, so that every
    plan stops on the road: the task ends at the destination and nothing leads on. Without them the frame runs on past
    the end, and a car that had reached its destination drove off the end of the map (upstream's roundabout-generic-v0
    exit road, within the 17 s episode), which upstream counts as off the road. Without a destination the road is
    taken to go on as the env has it: upstream's merge-v0 ends its episode 10 m before its road ends, and a wall at
    every dead end slowed the car there from 20.55 to 18.71 m/s (docs/controller.md)."""
    band = frame.dead_end
    if (band is None or destination not in frame.roads
            or frame.roads.index(band.road) < frame.roads.index(destination)
            or not s - DEAD_END_WALL < band.s_to <= s + max(preview.dead_end_distance, speed * preview.dead_end_time)):
        return []
    return [Neighbour(x=band.s_to + 0.5 * DEAD_END_WALL, y=band.first_center + k * band.lane_width, length=DEAD_END_WALL,
                      width=band.lane_width, yaw=0.0) for k in range(band.num_lanes)]


def target_lane_center(vehicle: Any, frame: RoadFrame, near_s: float) -> float | None:
    """[m] the frame's d of the centre of the lane ``vehicle`` steers to (highway-env's ``target_lane_index``), beside
    the vehicle; None for an object without one or where the frame does not reach it."""
    index = getattr(vehicle, "target_lane_index", None)
    if index is None:
        return None
    lane = vehicle.road.network.get_lane(index)
    longitudinal, _ = lane.local_coordinates(vehicle.position)
    found = frame.locate(np.asarray(lane.position(longitudinal, 0.0)), near_s)
    return None if found is None else float(found[1])


def _read(env: Any, task: Any, preview: RoadPreview, period: float | None = None
          ) -> tuple[Scene, Motion, RoadFrame, Goal | None]:
    """(scene, the ego's motion, the frame, the route's goal or None) of the current simulator state; ``task``: its
    ``v_des`` [m/s], ``name``, optional ``route`` (node names) and ``time_gap`` [s]; ``period`` [s]: until the next
    decision (default: the env's policy period)."""
    sim = env.unwrapped
    ego_vehicle = sim.vehicle
    if ego_vehicle is None or sim.road is None:
        raise ObservationError("the env has no road or ego vehicle: call env.reset(seed=...) first")
    route = getattr(task, "route", None)
    frame, me = ego_frame(env, route)
    ahead = max(me.speed, 0.0)
    lane_preview = max(preview.lane_distance, ahead * preview.lane_time)
    goal, split, route_gap = None, None, 0.0  # route_gap [s]: the time gap the route's lane changes keep (while any remain)
    followed = route or getattr(ego_vehicle, "route", None)
    if followed:
        # a split up to BRANCH_DISTANCE behind counts too, for a car on a road off the route: the route's road holds
        # a car that far past its end, and its frame leads on along the route, where that car has no lane
        off_route = tuple(ego_vehicle.lane_index[:2]) not in route_roads(followed)
        split = find_split(sim.road.network, frame, me.x - (BRANCH_DISTANCE if off_route else 0.0))
        if split is not None and missed(split, me.x, me.y, me.speed, preview.route_change):
            frame, me = ego_frame(env, ())  # the split is out of reach: straight on, a lane that still leads somewhere
            split = None
        elif split is not None and split.s < me.x:  # passed in the route's lanes: the next split, if any
            split = find_split(sim.road.network, frame, me.x)
        if split is not None:  # the goal (its band from settle_distance before the split) leads out of the other lanes
            lane_preview = min(lane_preview, max(split.s - settle_distance(me.speed, preview.route_change) - me.x, 0.0))
    road = frame.road(me.x, lane_preview, max(preview.curvature_distance, ahead * preview.curvature_time),
                      behind=0.5 * me.length, per_node=preview.curvature_per_node, d=me.y,
                      gap_preview=max(preview.lane_gap_distance, ahead * preview.lane_gap_time))
    try:
        ego = EgoState(x=me.x, y=me.y, vx=me.vx, vy=me.vy, ax=me.ax, ay=me.ay, length=me.length, width=me.width,
                       yaw=me.heading)
        neighbours = []
        others = [v for v in sim.road.vehicles if v is not ego_vehicle]
        others += [o for o in sim.road.objects if getattr(o, "collidable", True)]
        times = np.arange(0.0, preview.crossing_horizon + 1e-9, preview.crossing_step)
        for other in others:
            if getattr(other, "crashed", False) and hasattr(other, "route"):  # a vehicle's wreck: sliding to a stop
                neighbours.append(wreck_neighbour(other, frame, times, me.x))
                continue
            if hasattr(other, "route"):  # another road's vehicle, or one whose lanes leave its own: along them
                along = crossing_neighbour if may_cross(other, frame) else lane_leaving_neighbour
                crossing = along(other, frame, times, me.x, ego_vehicle)
                if crossing is not None:
                    neighbours.append(crossing)
                    continue
            m = vehicle_motion(other, frame, near_s=me.x)
            if m is None:  # beyond the frame: the far side of the graph
                continue
            accel = (m.ax * m.vx + m.ay * m.vy) / m.speed if m.speed > 1e-6 else 0.0  # along the velocity
            center = target_lane_center(other, frame, m.x) if preview.target_lanes else None
            neighbours.append(Neighbour(x=m.x, y=m.y, vx=m.vx, vy=m.vy, length=m.length, width=m.width, yaw=m.heading,
                                        accel=accel, lane_center=center))
        if split is not None:
            flows = entry_flows(split, me.x, me.y, neighbours)
            goal = split_goal(split, me.x, me.y, me.speed, preview.route_change, flows)
            if lanes_to_change(split, me.y) > 0:
                route_gap = preview.route_change.time_gap
        planned = route_roads(route)
        neighbours += dead_end_walls(frame, me.x, ahead, preview, planned[-1] if planned else None)
        if period is None:
            period = 1.0 / float(sim.config.get("policy_frequency", math.inf))
        v_des = curve_speed(frame, me.x, me.y, float(task.v_des), preview, period)
        # a curve ahead that lowers the desired speed (below the one with no curve ahead counted) is slowed for at once
        lowered = preview.slowing and v_des < curve_speed(frame, me.x, me.y, float(task.v_des),
                                                          dataclasses.replace(preview, speed_distance=0.0))
        margin = EllipseMargin(time_gap=max(getattr(task, "time_gap", 0.0), route_gap))
        scene = Scene(ego=ego, road=road, neighbours=tuple(neighbours), v_des=v_des,
                      slowing=0.0 if lowered else preview.slowing, ellipse_margin=margin, name=task.name)
    except ProblemError as exc:
        raise ObservationError(f"simulator state at t = {sim.steps / sim.config['simulation_frequency']:.2f} s: {exc}") from None
    return scene, me, frame, goal


def scene_from_env(env: Any, task: Any, preview: RoadPreview = RoadPreview()) -> Scene:
    """Scene of the current simulator state (``v_des``, name: the task's, e.g. a scenario)."""
    return _read(env, task, preview)[0]


def perceive(env: Any, task: Any, preview: RoadPreview = RoadPreview(), period: float | None = None) -> Perception:
    """The planning scene, its frame and the ego's kinematics, read once; ``task``: anything with ``v_des`` [m/s] and
    ``name`` (a :class:`~driveopt.sim.scenarios.Scenario`, a :class:`Task`), and optionally ``route``; ``period`` [s]:
    until the next decision, which the curves' desired speed allows for (default: the env's policy period)."""
    scene, me, frame, goal = _read(env, task, preview, period)
    world = EgoKinematics(speed=me.speed, heading=wrap_angle(float(env.unwrapped.vehicle.heading)))
    return Perception(scene, EgoKinematics(speed=me.speed, heading=me.heading), frame, world, goal)


@dataclass(frozen=True)
class Task:
    """What a driver is asked to do on a user's env: its desired speed, a name for records, optionally a route, and the
    time gap its plans keep to the cars in the lanes (:class:`~driveopt.scene.EllipseMargin`)."""

    v_des: float  # [m/s]
    name: str = "env"
    route: Sequence[str] | None = None  # node names of highway-env's lane graph, e.g. ("0", "1", "2", "exit")
    time_gap: float = 0.0  # [s]
