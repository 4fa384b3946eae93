"""Crossing traffic in the road frame: a neighbour predicted along its own lanes, mapped onto the frame node by node.

A highway-env vehicle that drives on a road the frame does not follow (an intersection's other arm, a roundabout's
entry) may cross the route's lanes. Its future poses follow its route's lanes at its speed held (as the simulator's
``ControlledVehicle.predict_trajectory_constant_speed``, :func:`_along_route`), stopping behind the ego where the ego
stands on them (as upstream's IDM does for the car in front), or, for a vehicle without a route, its velocity held in
world coordinates. Where its lanes meet at an angle (a roundabout's entry) it is steered through the joint by its own
lateral controller (:func:`_steered`): along the lanes' centres it turned the whole angle at once and crossed the
ring's outer lane about 0.3 s and 4 m (at 16 m/s) before the real car, so plans passed just behind a car that was
still crossing. Each pose is mapped into the frame
(:meth:`driveopt.sim.road_frame.RoadFrame.locate`) with its heading relative to the route there; a pose beside the
frame keeps its coordinates along it (off the road), one beyond its ends is put far behind the ego. The vehicle
becomes a :class:`~driveopt.prediction.PathNeighbour`: an obstacle at the nodes where its path is near the route and
far from it elsewhere (:func:`driveopt.prediction.path_phases` bounds its box by its heading phase by phase). That
covers a car crossing the route, one crossing a junction to join it (whose velocity, read in the frame at its
heading now, says nothing of where it will drive) and one that never enters the route's lanes (an oncoming road
beside the route: the usual prediction would keep it on the route's lanes). Whether the ego waits for it or goes
first is the optimiser's choice, like any other obstacle. A car whose path enters the route's lanes without ever
running at more than :data:`~driveopt.sim.road_frame.CROSSING_ANGLE` to them, on the frame or beside it (an
on-ramp's), and vehicles on the frame's own roads are left to the usual prediction, unless their route's lanes move
them across the frame's lanes (:func:`lane_leaving_neighbour`: a roundabout's inner lane into the exit the route takes
from the outer one). Beside the frame counts too: a
car turning towards the route from beyond the frame's lateral reach may have no node on the frame while it turns (at
8 m/s a 0.5 s node step is 4 m), and the usual prediction would carry its heading now straight across the lanes.
Beside it once the path has left it does not (a car gone straight on past the split the route leaves by, beside a
frame that turns into the exit: it keeps its lane until there, a lane follower).
A crashed vehicle, wherever it is, slides to a stop along its heading as highway-env brakes it
(:func:`wreck_neighbour`): traffic's own collisions at junctions send wrecks sliding into the route's lanes, where
a prediction along their lanes at their speed does not put them.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from driveopt.prediction import PathNeighbour
from driveopt.sim.lane_graph import wrap_angle
from driveopt.sim.road_frame import CORNER_ANGLE, CROSSING_ANGLE, RoadFrame

FAR_BEHIND = 1000.0  # [m] a pose beyond the frame's ends is put this far behind the ego
MAX_OFFSET = 200.0  # [m] a pose beside the frame is kept within this lateral offset of it
LANE_SHIFT = 2.0  # [m] half a lane: a routed vehicle on the frame's roads whose lanes move it further across the
# frame's is predicted along them (:func:`lane_leaving_neighbour`)
STEER_STEP = 1.0 / 15.0  # [s] a steered prediction's step: upstream's simulation step (15 Hz)
SETTLE_TIME = 1.5  # [s] ... which runs this long past the last joint at an angle, then the lanes' centres take over
MIN_STEERED_SPEED = 0.5  # [m/s] a slower vehicle is predicted along its lanes
KINK_GAP = 0.5  # [m] lanes whose joint leaves this gap meet at a kink too
YIELD_GAP = 4.0  # [m] a routed vehicle with the ego on its lanes ahead is predicted to stop this far behind it (bumpers):
# upstream's IDM, closing on a standing car at 5-16 m/s, comes to 4.2-4.5 m and settles at 5 (its DISTANCE_WANTED less a
# car's length); predicted nearer, a car waiting for a standing ego stands inside its collision ellipse, every plan infeasible
WRECK_TIME_CONSTANT = 1.0  # [s] highway-env brakes a crashed vehicle at -speed [m/s^2] with its wheels straight: its
# speed decays as exp(-t / this), and it slides speed x this [m] along its heading before it stands


def _along_route(vehicle: Any, times: np.ndarray, ego: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """(positions (K, 2) [m], headings (K,) [rad]) of a routed vehicle at ``times`` [s] from now, its speed held along
    its route's lanes (as upstream's ``predict_trajectory_constant_speed``, which picks a lane of a road of the route
    that names none by the lane count of the vehicle's road, not of that road, and fails where a two-lane road leads
    to a one-lane one, as at roundabout-v0's exits): a road of the route that names no lane is followed in the
    vehicle's lane number, or the road's last lane when it has fewer. Where ``ego`` (a vehicle) stands on one of those
    lanes ahead, the vehicle stops behind it (:data:`YIELD_GAP`), as highway-env's IDM stops for the car in front on
    its lane: a car already in a crossing's path is passed by nothing, so holding or clearing it can be planned.
    Where two of its lanes meet at an angle (:func:`_last_kink`: a roundabout's entry, 47-59 degrees at roundabout-v0)
    it steers through the joint as its own controller does (:func:`_steered`), not along the lanes' centres."""
    network = vehicle.road.network
    route = list(vehicle.route or [vehicle.lane_index])
    lane_number = vehicle.lane_index[2]

    def lane_of(index: tuple) -> Any:
        lanes = network.graph[index[0]][index[1]]
        return lanes[index[2] if index[2] is not None else min(lane_number, len(lanes) - 1)]

    lanes = [lane_of(index) for index in route]
    start = float(vehicle.lane.local_coordinates(np.asarray(vehicle.position, dtype=float))[0])
    gap = 0.5 * (float(vehicle.LENGTH) + (float(ego.LENGTH) if ego is not None else 0.0)) + YIELD_GAP  # [m] centres
    speed, times = float(vehicle.speed), np.asarray(times, dtype=float)
    reach = start + speed * float(np.max(times, initial=0.0)) + gap
    stop = math.inf if ego is None else _ego_along(lanes, np.asarray(ego.position, dtype=float), start, reach) - gap
    steered_until = -math.inf  # [s] the poses up to this time come from the vehicle's own steering
    kink = _last_kink(lanes, reach)
    if speed < -MIN_STEERED_SPEED and hasattr(vehicle, "steering_control"):  # rolling backwards (see _steered)
        steered_until = float(np.max(times, initial=0.0))
        steered_t, steered_positions, steered_headings, _ = _steered(vehicle, lanes, math.inf, steered_until)
    elif kink is not None and speed > MIN_STEERED_SPEED and hasattr(vehicle, "steering_control"):
        end = min(float(np.max(times, initial=0.0)), max(kink - start, 0.0) / speed + SETTLE_TIME)
        steered_t, steered_positions, steered_headings, along = _steered(vehicle, lanes, stop, end)
        steered_until = float(steered_t[-1])
        start = along - speed * steered_until  # the lanes' poses after it continue from where the steering ends
    positions, headings = [], []
    for t in times:
        if t <= steered_until:  # between the steps' poses
            positions.append([np.interp(t, steered_t, column) for column in steered_positions.T])
            headings.append(np.interp(t, steered_t, steered_headings))
            continue
        longitudinal, k, lane = min(start + speed * t, max(stop, start)), 0, lanes[0]
        while k < len(lanes) - 1 and longitudinal > float(lane.length):
            longitudinal -= float(lane.length)
            k += 1
            lane = lanes[k]
        positions.append(lane.position(longitudinal, 0.0))
        headings.append(lane.heading_at(longitudinal))
    return np.asarray(positions, dtype=float).reshape(len(headings), 2), np.asarray(headings, dtype=float)


def _last_kink(lanes: list[Any], reach: float) -> float | None:
    """[m] the distance along ``lanes`` (from the first one's start) of the last joint before ``reach`` [m] where one
    lane's end and the next one's start differ in heading by more than :data:`~driveopt.sim.road_frame.CORNER_ANGLE`
    or lie :data:`KINK_GAP` apart; None when there is none."""
    kink, offset = None, 0.0
    for before, after in zip(lanes[:-1], lanes[1:]):
        offset += float(before.length)
        if offset > reach:
            break
        turn = wrap_angle(float(after.heading_at(0.0)) - float(before.heading_at(float(before.length))))
        gap = float(np.hypot(*(np.asarray(after.position(0.0, 0.0)) - before.position(float(before.length), 0.0))))
        if abs(turn) > CORNER_ANGLE or gap > KINK_GAP:
            kink = offset
    return kink


def _steered(vehicle: Any, lanes: list[Any], stop: float, end: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(times [s], positions (n, 2) [m], headings [rad], [m] the distance along ``lanes`` at the last time) of
    ``vehicle`` driven by its own lateral controller (highway-env's ``ControlledVehicle.steering_control`` with the
    vehicle's gains, its kinematic bicycle, one :data:`STEER_STEP` at a time) along ``lanes`` at its speed held, from
    its pose now until ``end`` [s]; its target moves to the next lane half a car before a lane's end (the lane's
    ``after_end``), and it stands once it is ``stop`` [m] along them (upstream's IDM brakes for the car in front);
    distances along them from the first lane's start, where the vehicle is now. A vehicle rolling backwards (upstream's
    IDM brakes a car below 0 m/s when the car in front is too close: intersection-v0's traffic yielding to the ego) is
    steered by the same law at its negative speed, which turns its heading away from its lane's, ever faster: its
    front swings across the lanes beside it (a car yielding at intersection-v0 turned 38 degrees in 2.4 s at -1 m/s
    and struck the ego passing it, predicted backing along its lane)."""
    position = np.asarray(vehicle.position, dtype=float).copy()
    heading, speed, half = float(vehicle.heading), float(vehicle.speed), 0.5 * float(vehicle.LENGTH)
    kp_lateral, kp_heading, pursuit = float(vehicle.KP_LATERAL), float(vehicle.KP_HEADING), float(vehicle.TAU_PURSUIT)
    max_steering = float(vehicle.MAX_STEERING_ANGLE)
    k, offset = 0, 0.0  # the lane it follows, [m] the length of the lanes before it

    def locate() -> tuple[Any, float, float]:
        """(the lane it follows, [m] longitudinal and lateral on it) at ``position``, moving on to the next lane."""
        nonlocal k, offset
        lane = lanes[k]
        longitudinal, lateral = lane.local_coordinates(position)
        if k < len(lanes) - 1 and lane.after_end(position, longitudinal, lateral):
            offset += float(lane.length)
            k += 1
            lane = lanes[k]
            longitudinal, lateral = lane.local_coordinates(position)
        return lane, float(longitudinal), float(lateral)

    out_t, out_p, out_h = [0.0], [position.copy()], [heading]
    for n in range(1, int(math.ceil(end / STEER_STEP)) + 1):
        lane, longitudinal, lateral = locate()
        along = offset + longitudinal
        v = speed if speed < 0.0 else min(speed, max(stop - along, 0.0) / STEER_STEP)  # [m/s] it stands at stop
        if v != 0.0:
            future = float(lane.heading_at(longitudinal + v * pursuit))
            heading_ref = future + float(np.clip(math.asin(float(np.clip(-kp_lateral * lateral / v, -1.0, 1.0))),
                                                 -math.pi / 4, math.pi / 4))
            rate = kp_heading * wrap_angle(heading_ref - heading)
            slip = math.asin(float(np.clip(half / v * rate, -1.0, 1.0)))
            beta = math.atan(0.5 * math.tan(float(np.clip(math.atan(2.0 * math.tan(slip)), -max_steering, max_steering))))
            position = position + v * STEER_STEP * np.array([math.cos(heading + beta), math.sin(heading + beta)])
            heading += v * math.sin(beta) / half * STEER_STEP
        out_t.append(n * STEER_STEP)
        out_p.append(position.copy())
        out_h.append(heading)
    _, longitudinal, _ = locate()
    return np.asarray(out_t), np.asarray(out_p), np.asarray(out_h), offset + longitudinal


def _ego_along(lanes: list[Any], position: np.ndarray, start: float, reach: float) -> float:
    """[m] the distance along ``lanes`` (measured as ``start``, from the first lane's start) at which ``position``
    lies on one of them (upstream's ``on_lane(margin=1)``, what its IDM reads a car in front by: within the lane's half
    width and 1 m, and up to a car's length beyond its ends), between ``start`` and ``reach``; inf when it lies on
    none there."""
    offset = 0.0
    for lane in lanes:
        longitudinal, lateral = lane.local_coordinates(position)
        along = offset + float(longitudinal)
        if lane.on_lane(position, longitudinal, lateral, margin=1.0) and start < along <= reach:
            return along
        offset += float(lane.length)
        if offset > reach:
            break
    return math.inf


def _poses(vehicle: Any, times: np.ndarray, ego: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """(positions (K, 2) [m], headings (K,) [rad]) of ``vehicle`` at ``times`` [s] from now, world coordinates
    (crashed: sliding to a stop along its heading, :data:`WRECK_TIME_CONSTANT`; routed: along its lanes, stopping
    behind ``ego`` on them, :func:`_along_route`; else its velocity held)."""
    crashed = bool(getattr(vehicle, "crashed", False))
    if not crashed and getattr(vehicle, "route", None) and getattr(vehicle, "lane_index", None) is not None:
        return _along_route(vehicle, times, ego)
    heading, speed, t = float(vehicle.heading), float(vehicle.speed), np.asarray(times, dtype=float)
    travelled = speed * WRECK_TIME_CONSTANT * -np.expm1(-t / WRECK_TIME_CONSTANT) if crashed else speed * t
    direction = np.array([math.cos(heading), math.sin(heading)])
    return np.asarray(vehicle.position, dtype=float) + travelled[:, None] * direction, np.full(len(t), heading)


def _frame_pose(frame: RoadFrame, position: np.ndarray, ego_x: float) -> tuple[float, float, Any, float, bool] | None:
    """(s, d [m], piece, longitudinal [m], whether the frame places it) of a world position: where the frame places it
    (:meth:`RoadFrame.locate`), else its coordinates along the piece whose range holds it, nearest laterally (d kept
    within :data:`MAX_OFFSET`: beside the road, not on it), else None (beyond the frame's curved ends)."""
    found = frame.locate(position, near_s=ego_x)
    if found is not None:
        s, d, piece, longitudinal, _ = found
        return s, d, piece, longitudinal, True
    best = None
    for piece in frame.pieces:
        longitudinal, lateral = piece.lane.local_coordinates(position)
        if piece.covers(longitudinal) and (best is None or abs(lateral) < abs(best[1])):
            best = (piece.s_start + float(longitudinal), float(lateral), piece, float(longitudinal))
    if best is None:
        return None
    s, lateral, piece, longitudinal = best
    return s, float(np.clip(piece.d_shift + lateral, -MAX_OFFSET, MAX_OFFSET)), piece, longitudinal, False


def may_cross(vehicle: Any, frame: RoadFrame) -> bool:
    """Whether ``vehicle`` drives (or is routed) on a road the frame does not follow: only those can cross it."""
    roads = set(frame.roads)
    lane = getattr(vehicle, "lane_index", None)
    route = getattr(vehicle, "route", None) or []
    return any(index is not None and (index[0], index[1]) not in roads for index in [lane, *route])


def _path(vehicle: Any, frame: RoadFrame, times: np.ndarray, ego_x: float, ego: Any = None
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool, bool, float]:
    """(s, d [m], heading relative to the route [rad], each (K,); whether the path enters the route's lanes; whether it
    runs at more than CROSSING_ANGLE to them; [m] how far its offset on the frame moves) of ``vehicle``'s poses at
    ``times`` [s] mapped onto the frame (:func:`crossing_neighbour`)."""
    positions, headings = _poses(vehicle, times, ego)
    xs, ys, yaws = np.full(len(times), ego_x - FAR_BEHIND), np.zeros(len(times)), np.zeros(len(times))
    enters = turned = False
    placed = []  # [m] offsets of the poses the frame places
    left = False  # whether the path has been on the frame and left it
    for k, (position, heading) in enumerate(zip(positions, headings)):
        found = _frame_pose(frame, position, ego_x)
        if found is None:
            continue
        s, d, piece, longitudinal, on_frame = found
        yaw = wrap_angle(float(heading) - float(piece.lane.heading_at(longitudinal)))
        xs[k], ys[k], yaws[k] = s, d, yaw
        enters |= on_frame and any(b.low < d < b.high and b.s_from <= s <= b.s_to for b in piece.bands)
        left |= bool(placed) and not on_frame
        # on the frame or beside it before reaching it; not once it has left (a car gone straight on past the split
        # the route leaves by, beside a frame that turns into the exit)
        turned |= not left and CROSSING_ANGLE < abs(yaw) < math.pi - CROSSING_ANGLE
        if on_frame:
            placed.append(d)
    return xs, ys, yaws, enters, turned, float(np.ptp(placed)) if placed else 0.0


def _path_neighbour(vehicle: Any, times: np.ndarray, xs: np.ndarray, ys: np.ndarray, yaws: np.ndarray) -> PathNeighbour:
    return PathNeighbour(x=float(xs[0]), y=float(ys[0]), length=float(vehicle.LENGTH), width=float(vehicle.WIDTH),
                         yaw=float(yaws[0]), t=tuple(times), path_x=tuple(xs), path_y=tuple(ys), path_yaw=tuple(yaws))


def crossing_neighbour(vehicle: Any, frame: RoadFrame, times: np.ndarray, ego_x: float,
                       ego: Any = None) -> PathNeighbour | None:
    """``vehicle`` as a :class:`PathNeighbour` over ``times`` [s] (the planner's nodes), or None when its path joins
    the route's lanes at a shallow angle (see the module docstring); ``ego_x`` [m]: the ego's arc length; ``ego``:
    the ego vehicle, which a routed vehicle stops behind where it stands on its lanes."""
    times = np.asarray(times, dtype=float)
    xs, ys, yaws, enters, turned, _ = _path(vehicle, frame, times, ego_x, ego)
    if enters and not turned:  # joining at a shallow angle: the usual prediction
        return None
    return _path_neighbour(vehicle, times, xs, ys, yaws)


def wreck_neighbour(vehicle: Any, frame: RoadFrame, times: np.ndarray, ego_x: float) -> PathNeighbour:
    """A crashed ``vehicle`` as a :class:`PathNeighbour` over ``times`` [s], wherever it is: sliding to a stop along
    its heading (:data:`WRECK_TIME_CONSTANT`), not on along its lanes at its speed."""
    times = np.asarray(times, dtype=float)
    xs, ys, yaws, _, _, _ = _path(vehicle, frame, times, ego_x)
    return _path_neighbour(vehicle, times, xs, ys, yaws)


def lane_leaving_neighbour(vehicle: Any, frame: RoadFrame, times: np.ndarray, ego_x: float,
                           ego: Any = None) -> PathNeighbour | None:
    """A routed ``vehicle`` on the frame's own roads as a :class:`PathNeighbour` (as :func:`crossing_neighbour`) when
    its route's lanes move it more than :data:`LANE_SHIFT` across the frame's (a roundabout's inner lane into the
    exit the route takes too, which starts from the outer one), else None: the usual prediction keeps it in its lane,
    and the ego in the outer lane met it there as it cut across to the exit."""
    if not getattr(vehicle, "route", None):
        return None
    times = np.asarray(times, dtype=float)
    xs, ys, yaws, _, _, shift = _path(vehicle, frame, times, ego_x, ego)
    return _path_neighbour(vehicle, times, xs, ys, yaws) if shift > LANE_SHIFT else None
