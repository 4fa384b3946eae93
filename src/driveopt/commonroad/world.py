"""A CommonRoad scenario as driveopt's world: the route's reference path as the road frame, the lanes beside it as a
:class:`~driveopt.scene.Road`, the scenario's obstacles as neighbours with their recorded futures, and the planning
problem's goal as a :class:`~driveopt.goal.Goal`.

- Route: CommonRoad's route planner (the first route); the reference path is the centre line of the route's first
  lanelet and its successors (a successor on the route first), so a route's lane change is a goal band, not a bend.
- Road at a station: the drivable area (every lanelet, one-way or not) cut across the reference path at the ego's
  station and every 5 m over a preview of 3 s at its speed (at least 15 m); the stretch holding the ego, narrowed to what
  stays drivable over the preview, split into lanes of the scenario's typical lanelet width.
- Obstacles: each dynamic obstacle's recorded state at the time step (static ones always), turned into the frame; their
  future over the planning horizon is the recording (ground-truth prediction), continued at constant velocity after it.
- Goal: the goal region's lateral extent as a band, its longitudinal extent as the x range, its speed and time windows;
  the band widens before the goal's start by a lane per :data:`LANE_TIME` of travel (``Goal.widen``), so that it is
  required only as late as lane changes can still reach it: a band imposed in full from 60 m before the goal, while
  the car passed a slow car in the lane on the other side of it, asked for two lanes at once beside that car (no plan).

:class:`UnsupportedScenario` (one line) for what the frame cannot represent: several or no planning problems, no
route, an ego that starts off the lanelets, a reference path that bends more sharply than :data:`MAX_CURVATURE`, or an
obstacle that is not a rectangle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from driveopt.commonroad.path import PathFrame
from driveopt.errors import DriveoptError
from driveopt.goal import Goal
from driveopt.scene import EgoState, EllipseMargin, Neighbour, Road, Scene

MAX_CURVATURE = 0.1  # [1/m] sharpest bend of the reference path the straight-road planner is given (radius 10 m)
VEHICLE = "VW_VANAGON"  # CommonRoad's vehicle parameters for the ego (FISS's benchmark uses the same)
# [m] clearance added to the collision ellipses: none across the road, whose ellipses around a box already clear it by
# 0.2 (driveopt.commonroad.cover's segments) or sqrt(2) - 1 (the single ellipse) of its half-width
ELLIPSE_MARGIN = EllipseMargin(longitudinal=0.5, lateral=0.0)
# the goal's band widens by a lane per LANE_TIME of travel at the goal's speed (at least MIN_LANE_DISTANCE) before its
# start (Goal.widen), so a band far ahead accepts every lane it can still be reached from, and is required only then
LANE_TIME, MIN_LANE_DISTANCE = 1.5, 20.0  # [s], [m]
PREVIEW_TIME, PREVIEW_MIN, PREVIEW_STEP = 3.0, 15.0, 5.0  # [s], [m], [m] of the lane preview


class UnsupportedScenario(DriveoptError):
    """The scenario cannot be represented in driveopt's road frame (the message says why, in one line)."""


@dataclass(frozen=True)
class Track:
    """An obstacle's recorded motion in the frame."""

    id: int
    length: float  # [m]
    width: float  # [m]
    static: bool
    steps: np.ndarray  # (T,) time steps with a state
    s: np.ndarray  # (T,) [m]
    d: np.ndarray  # (T,) [m]
    vs: np.ndarray  # (T,) [m/s] along the frame
    vd: np.ndarray  # (T,) [m/s] across it
    yaw: np.ndarray  # (T,) [rad] relative to the frame

    def index(self, step: int) -> int | None:
        if self.static:
            return 0
        i = int(np.searchsorted(self.steps, step))
        return i if i < len(self.steps) and self.steps[i] == step else None

    def future(self, step: int, times: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(s, d) [m] at ``times`` [s] after ``step``: the recording, then constant velocity from its last state."""
        if self.static:
            return np.full(len(times), self.s[0]), np.full(len(times), self.d[0])
        at = step + times / dt
        last = float(self.steps[-1])
        s = np.interp(np.minimum(at, last), self.steps, self.s) + self.vs[-1] * np.maximum(at - last, 0.0) * dt
        d = np.interp(np.minimum(at, last), self.steps, self.d) + self.vd[-1] * np.maximum(at - last, 0.0) * dt
        return s, d


class CommonRoadWorld:
    """One scenario's road frame, road, obstacles and goal (see the module docstring)."""

    def __init__(self, path: str | Path) -> None:
        from commonroad.common.file_reader import CommonRoadFileReader
        from commonroad_dc.feasibility.vehicle_dynamics import VehicleParameterMapping

        self.path = Path(path)
        self.name = self.path.stem
        try:
            scenario, problems = CommonRoadFileReader(str(path)).open()
        except Exception as exc:  # noqa: BLE001 - the reader raises many kinds on a bad file
            raise UnsupportedScenario(f"{self.name}: commonroad-io cannot read it ({type(exc).__name__}: "
                                      f"{' '.join(str(exc).split())[:120]})") from None
        planning = list(problems.planning_problem_dict.values())
        if len(planning) != 1:
            raise UnsupportedScenario(f"{self.name}: {len(planning)} planning problems; driveopt plans for exactly one")
        self.scenario, self.problem = scenario, planning[0]
        self.dt = float(scenario.dt)
        params = VehicleParameterMapping[VEHICLE].value
        self.length, self.width = float(params.l), float(params.w)  # [m]
        start = self.problem.initial_state
        self.start_step = int(start.time_step)
        network = scenario.lanelet_network
        position = np.asarray(start.position, dtype=np.float64)
        if not network.find_lanelet_by_position([position])[0]:
            raise UnsupportedScenario(f"{self.name}: the ego starts at ({position[0]:.1f}, {position[1]:.1f}) m, on no "
                                      "lanelet")
        self.frame = PathFrame(self._reference(network))
        bend = float(np.max(np.abs(self.frame.curvature(np.linspace(0.0, self.frame.length, 200)))))
        if bend > MAX_CURVATURE:
            raise UnsupportedScenario(f"{self.name}: the route bends with curvature {bend:.2f} 1/m, more sharply than "
                                      f"{MAX_CURVATURE:g} 1/m (radius {1 / MAX_CURVATURE:g} m): driveopt plans along "
                                      "roads, not through turns at junctions")
        self._drivable(network)
        self.tracks = [self._track(o) for o in scenario.obstacles]
        self.goal = self._goal()

    # --- construction ---------------------------------------------------------------------------------------------
    def _reference(self, network: Any) -> np.ndarray:
        from commonroad_route_planner.route_planner import RoutePlanner

        try:
            routes = RoutePlanner(network, self.problem, self.scenario).plan_routes()
        except Exception as exc:  # noqa: BLE001 - the route planner raises assorted errors on maps it cannot route
            raise UnsupportedScenario(f"{self.name}: the route planner found no route ({type(exc).__name__})") from None
        if not routes:
            raise UnsupportedScenario(f"{self.name}: the route planner found no route to the goal")
        route = list(routes[0].lanelet_ids)
        self.route = route
        chain, seen = [route[0]], {route[0]}
        while True:
            successors = [i for i in network.find_lanelet_by_id(chain[-1]).successor if i not in seen]
            if not successors:
                break
            nxt = next((i for i in successors if i in route), successors[0])
            chain.append(nxt)
            seen.add(nxt)
        points = [network.find_lanelet_by_id(chain[0]).center_vertices]
        points += [network.find_lanelet_by_id(i).center_vertices[1:] for i in chain[1:]]
        return np.concatenate(points)

    def _drivable(self, network: Any) -> None:
        from shapely.ops import unary_union

        self.drivable = unary_union([lanelet.polygon.shapely_object.buffer(0.05) for lanelet in network.lanelets])
        widths = [np.median(np.linalg.norm(lanelet.left_vertices - lanelet.right_vertices, axis=1))
                  for lanelet in network.lanelets]
        self.lane_width = float(np.median(widths))  # [m]

    def _track(self, obstacle: Any) -> Track:
        from commonroad.geometry.shape import Rectangle

        shape = obstacle.obstacle_shape
        if not isinstance(shape, Rectangle):
            raise UnsupportedScenario(f"{self.name}: obstacle {obstacle.obstacle_id} is a {type(shape).__name__}; "
                                      "driveopt plans around rectangles only")
        states = [obstacle.initial_state]
        prediction = getattr(obstacle, "prediction", None)
        trajectory = getattr(prediction, "trajectory", None)
        if trajectory is not None:
            states += [st for st in trajectory.state_list if st.time_step > obstacle.initial_state.time_step]
        xy = np.array([st.position for st in states], dtype=np.float64)
        s, d = self.frame.project(xy)
        rel = np.array([float(getattr(st, "orientation", 0.0) or 0.0) for st in states]) - self.frame.heading(s)
        rel = np.arctan2(np.sin(rel), np.cos(rel))
        v = np.array([float(getattr(st, "velocity", 0.0) or 0.0) for st in states])
        static = trajectory is None
        return Track(obstacle.obstacle_id, float(shape.length), float(shape.width), static,
                     np.array([st.time_step for st in states]), s, d, v * np.cos(rel), v * np.sin(rel), rel)

    def _goal(self) -> Goal:
        goal_state = self.problem.goal.state_list[0]
        bands, x_range = [], None
        if goal_state.has_value("position"):
            shape = goal_state.position
            shapes = getattr(shape, "shapes", [shape])
            lows, highs = [], []
            for part in shapes:
                boundary = np.asarray(part.shapely_object.exterior.coords)
                s, d = self.frame.project(boundary)
                bands.append((float(d.min()), float(d.max())))
                lows.append(float(s.min()))
                highs.append(float(s.max()))
            x_range = (min(lows), max(highs))
        window = lambda name: (getattr(getattr(goal_state, name), "start", getattr(goal_state, name)),  # noqa: E731
                               getattr(getattr(goal_state, name), "end", getattr(goal_state, name)))
        speed = window("velocity") if goal_state.has_value("velocity") else None
        time = None
        if goal_state.has_value("time_step"):
            first, last = window("time_step")
            time = ((first - self.start_step) * self.dt, (last - self.start_step) * self.dt)
        speed = None if speed is None else tuple(map(float, speed))
        pace = 0.5 * (speed[0] + min(speed[1], 40.0)) if speed is not None else float(
            getattr(self.problem.initial_state, "velocity", 0.0) or 0.0)
        lane_distance = max(LANE_TIME * pace, MIN_LANE_DISTANCE)  # [m] of travel per lane the band widens by
        return Goal(bands=tuple(bands), x=x_range, speed=speed, time=time, widen=self.lane_width / lane_distance)

    # --- per step --------------------------------------------------------------------------------------------------
    def initial_ego(self) -> EgoState:
        """The planning problem's initial state in the frame."""
        st = self.problem.initial_state
        s, d = self.frame.project(np.asarray(st.position, dtype=np.float64))
        rel = float(st.orientation) - float(self.frame.heading(s))
        v = float(getattr(st, "velocity", 0.0) or 0.0)
        a = float(getattr(st, "acceleration", 0.0) or 0.0) if st.has_value("acceleration") else 0.0
        return EgoState(x=float(s), y=float(d), vx=v * math.cos(rel), vy=v * math.sin(rel), ax=a * math.cos(rel),
                        ay=a * math.sin(rel), length=self.length, width=self.width, yaw=rel)

    def road(self, s: float, d: float, speed: float) -> Road:
        """The lanes at station ``s`` [m] around offset ``d`` [m], narrowed to what stays drivable over the preview."""
        from shapely.geometry import LineString

        preview = max(PREVIEW_MIN, PREVIEW_TIME * abs(speed))
        low, high = -math.inf, math.inf
        for station in np.arange(s, s + preview + 1e-9, PREVIEW_STEP):
            ends = self.frame.to_world(np.array([station, station]), np.array([-50.0, 50.0]))
            cut = LineString(ends).intersection(self.drivable)
            pieces = [cut] if cut.geom_type == "LineString" else list(getattr(cut, "geoms", []))
            spans = []
            for piece in pieces:
                if piece.is_empty or piece.geom_type != "LineString":
                    continue
                _, offsets = self.frame.project(np.asarray(piece.coords))
                spans.append((float(offsets.min()), float(offsets.max())))
            near = d if station == s else 0.5 * (low + high)
            holding = [span for span in spans if span[0] - 0.5 <= near <= span[1] + 0.5]
            if not holding:
                if station == s:
                    raise UnsupportedScenario(f"{self.name}: no drivable lane at station {s:.1f} m, offset {d:.1f} m")
                break  # the road ends ahead: the bounds so far stand
            span = holding[0]
            low, high = max(low, span[0]), min(high, span[1])
            if high - low < self.width + 0.2:  # narrower than the car: keep what the ego's station allows
                break
        if not math.isfinite(low) or high - low < self.width + 0.2:
            raise UnsupportedScenario(f"{self.name}: the drivable width at station {s:.1f} m is below the car's")
        lanes = max(1, int(round((high - low) / self.lane_width)))
        width = (high - low) / lanes
        curvature = float(np.clip(self.frame.curvature(np.array([s]))[0], -MAX_CURVATURE, MAX_CURVATURE))
        return Road(num_lanes=lanes, lane_width=width, first_lane_center=low + 0.5 * width, curvature=curvature)

    def neighbours(self, step: int) -> list[tuple[Neighbour, Track]]:
        """The obstacles present at ``step``, in the frame, with their tracks."""
        out = []
        for track in self.tracks:
            i = track.index(step)
            if i is None:
                continue
            out.append((Neighbour(x=float(track.s[i]), y=float(track.d[i]), vx=float(track.vs[i]),
                                  vy=float(track.vd[i]), length=track.length, width=track.width,
                                  yaw=float(track.yaw[i])), track))
        return out

    def scene(self, step: int, ego: EgoState, v_des: float) -> tuple[Scene, list[tuple[Neighbour, Track]]]:
        """The scene at ``step`` for ``ego`` (in the frame) and the neighbours' tracks."""
        present = self.neighbours(step)
        road = self.road(ego.x, ego.y, ego.speed)
        return Scene(ego=ego, road=road, neighbours=tuple(n for n, _ in present), v_des=v_des, ellipse_margin=ELLIPSE_MARGIN,
                     name=self.name), present

    def cruise_speed(self) -> float:
        """[m/s] the desired speed before the goal's windows: the middle of the goal's speed window, else the initial
        speed (at least 10 m/s)."""
        if self.goal.speed is not None:
            return 0.5 * (self.goal.speed[0] + min(self.goal.speed[1], 40.0))
        return max(10.0, float(getattr(self.problem.initial_state, "velocity", 0.0) or 0.0))
