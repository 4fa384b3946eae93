"""What the planner assumes about the neighbours: their predicted motion, which ones count, their ellipses.

Neighbours are predicted with constant velocity, except that a braking one keeps braking for
:data:`BRAKING_TIME` (never reversing; a braking time of 0 is P1's constant velocity); the ones
that come closest to the ego within :data:`SELECTION_TIME` (the ego holding its velocity) are
planned against, each inside a collision ellipse that circumscribes the Minkowski sum of the two
vehicle boxes. Ranking by distance now instead (P1) drops a stopped car 45 m ahead of an ego at
20 m/s whenever ten cars are nearer, in dense traffic often until braking no longer avoids it.
A :class:`PathNeighbour` (crossing or merging traffic, predicted along its own lanes by the simulator side) carries
its predicted poses instead: it is where its path says at each node, and its ellipse is the smallest axis-aligned one
around the Minkowski sum of the ego's box and its boxes at the headings it has along the path; its heading phases
compete for the obstacle slots with every other neighbour (:func:`obstacle_slots`). Positions and times in the road
frame: metres, seconds.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from driveopt.scene import EgoState, EllipseMargin, Neighbour, ProblemError, Scene


@dataclass(frozen=True)
class PathNeighbour(Neighbour):
    """A neighbour with its predicted path in the road frame: poses (``x``, ``y`` [m], ``yaw`` [rad] relative to the
    road) at times ``t`` [s] from now, increasing. Between the times it is interpolated, beyond them held. Its box for
    the collision ellipse is the largest of the axis-aligned boxes around it at its headings along the path (a car
    crossing the route at a right angle is as wide as it is long across the road while it crosses)."""

    t: tuple[float, ...] = ()
    path_x: tuple[float, ...] = ()
    path_y: tuple[float, ...] = ()
    path_yaw: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        arrays = [np.asarray(getattr(self, f), dtype=float) for f in ("t", "path_x", "path_y", "path_yaw")]
        if not arrays[0].size or any(a.shape != arrays[0].shape for a in arrays) or arrays[0].ndim != 1:
            raise ProblemError("a PathNeighbour's t, path_x, path_y and path_yaw must be equally long, non-empty sequences")
        if not all(np.all(np.isfinite(a)) for a in arrays) or np.any(np.diff(arrays[0]) <= 0.0):
            raise ProblemError("a PathNeighbour's path must be finite, its times increasing")
        for f, a in zip(("t", "path_x", "path_y", "path_yaw"), arrays):
            object.__setattr__(self, f, tuple(float(v) for v in a))

    @property
    def half_extents(self) -> tuple[float, float]:
        """[m] the largest half-length and half-width of its axis-aligned boxes now and along the path."""
        yaws = self.yaws
        c, s = np.abs(np.cos(yaws)), np.abs(np.sin(yaws))
        return float(np.max(0.5 * (self.length * c + self.width * s))), float(np.max(0.5 * (self.length * s + self.width * c)))

    @property
    def yaws(self) -> np.ndarray:
        """[rad] its headings now and along the path."""
        return np.asarray((self.heading,) + self.path_yaw)


PHASE_TURN = math.radians(10.0)  # [rad] the most a PathNeighbour turns within one obstacle slot (20 deg before: a
# turning car's box leant up to 20 deg, 0.5 m wider across the route; intersection-v0 6.67 -> 6.88 m/s at 10 deg)


def path_phases(n: PathNeighbour, t: np.ndarray) -> list[tuple[PathNeighbour, np.ndarray]]:
    """A :class:`PathNeighbour`'s path split where it turns: (the neighbour over one phase, the boolean mask of the
    times ``t`` [s] in it), consecutive runs of ``t`` over which its heading stays within :data:`PHASE_TURN` of the
    run's first. Each phase's box is bounded by its own headings only, so a car that crosses the route and then
    drives beside it, oncoming, is as wide as it is long only while it crosses (one box for the whole path would
    reach into the ego's lane beside it). One phase when it never turns that much."""
    yaw = np.interp(t, n.t, np.unwrap(np.asarray(n.path_yaw)))
    starts = [0]
    for k in range(1, len(t)):
        if abs(yaw[k] - yaw[starts[-1]]) > PHASE_TURN:
            starts.append(k)
    phases = []
    for first, end in zip(starts, starts[1:] + [len(t)]):
        mask = np.zeros(len(t), dtype=bool)
        mask[first:end] = True
        inside = [k for k, tk in enumerate(n.t) if t[first] <= tk <= t[end - 1]]
        poses_t = tuple(t[first:end]) + tuple(n.t[k] for k in inside)
        order = np.argsort(poses_t, kind="stable")
        times = np.asarray(poses_t)[order]
        keep = np.concatenate([[True], np.diff(times) > 0.0])
        yaws = np.concatenate([yaw[first:end], [n.path_yaw[k] for k in inside]])[order][keep]
        xs = np.interp(times[keep], n.t, n.path_x)
        ys = np.interp(times[keep], n.t, n.path_y)
        phase = dataclasses.replace(n, x=float(xs[0]), y=float(ys[0]), yaw=float(yaws[0]), t=tuple(times[keep]),
                                    path_x=tuple(xs), path_y=tuple(ys), path_yaw=tuple(yaws))
        phases.append((phase, mask))
    return phases


def ellipse_semi_axes(ego: EgoState, other: Neighbour, margin: EllipseMargin) -> tuple[float, float]:
    """[m] semi-axes of an axis-aligned ellipse around the Minkowski sum of the two boxes, plus margins.

    The axis-aligned ellipse with semi-axes sqrt(2) * (A, B) passes through the corners of a
    box with half-sides (A, B): outside it, the two axis-aligned boxes cannot overlap. The
    neighbour's box is first replaced by the axis-aligned box around it at its heading, so a car
    turned across the road (changing lanes steeply, or stopped askew after a crash) is covered.
    A :class:`PathNeighbour` (crossing traffic, turned by any angle) gets instead the smallest axis-aligned ellipse
    around the Minkowski sum of the ego's box and its turned boxes at its headings (:func:`minkowski_ellipse`): for a
    car at 45 degrees to the route about a fifth less along it than the box around the turned box.
    A lane-following neighbour's longitudinal semi-axis also grows by ``margin.time_gap`` times the ego's forward speed.
    The ego's box here is the one along the road; while the ego is turned its box grows for the
    first seconds of the plan (:func:`ego_box_growth`).
    """
    if isinstance(other, PathNeighbour):
        a, b = minkowski_ellipse(0.5 * ego.length, 0.5 * ego.width, box_corners(other.length, other.width, other.yaws))
        return a + margin.longitudinal, b + margin.lateral
    other_long, other_lat = other.half_extents
    half_long = 0.5 * ego.length + other_long
    half_lat = 0.5 * ego.width + other_lat
    headway = margin.time_gap * max(ego.vx, 0.0)  # [m]
    return math.sqrt(2.0) * half_long + margin.longitudinal + headway, math.sqrt(2.0) * half_lat + margin.lateral


def box_corners(length: float, width: float, yaws: np.ndarray) -> np.ndarray:
    """[m] (4 M, 2) corners, relative to its centre, of a box of ``length`` x ``width`` [m] turned by each of the M
    ``yaws`` [rad]."""
    c, s = np.cos(np.ravel(yaws))[:, None], np.sin(np.ravel(yaws))[:, None]
    along = 0.5 * length * np.array([1.0, 1.0, -1.0, -1.0])
    across = 0.5 * width * np.array([1.0, -1.0, 1.0, -1.0])
    return np.stack([c * along - s * across, s * along + c * across], axis=-1).reshape(-1, 2)


_CANDIDATE_CHUNK = 32  # [-] candidate ellipses checked against every point at once in :func:`minkowski_ellipse`


def minkowski_ellipse(half_long: float, half_lat: float, corners: np.ndarray) -> tuple[float, float]:
    """[m] (a, b): the smallest-area centred axis-aligned ellipse x^2/a^2 + y^2/b^2 <= 1 that contains the Minkowski
    sum of the axis-aligned box (+-``half_long``, +-``half_lat``) and the convex hull of ``corners`` (M, 2) [m]
    (a centrally symmetric set: each corner's reflection is among them, as :func:`box_corners` gives them).

    An axis-aligned centred ellipse is symmetric in both axes, so it contains the sum where it contains the points
    (|x| + half_long, |y| + half_lat); with u = 1/a^2, v = 1/b^2 the containment is linear (x^2 u + y^2 v <= 1) and
    the area ~ 1/sqrt(uv). The optimum of max uv over that polygon is at one constraint's own optimum (u = 1/(2 x^2),
    v = 1/(2 y^2)) or where two of them meet; every candidate is checked against all points. For a single box (every
    corner reflecting the others in both axes) it is sqrt(2) times its half-sides."""
    points = np.abs(np.asarray(corners, dtype=float)) + np.array([half_long, half_lat])
    # only the points no other point exceeds in both coordinates can be on the ellipse
    keep = ~np.any((points[None, :, 0] >= points[:, None, 0]) & (points[None, :, 1] >= points[:, None, 1])
                   & np.any(points[None, :, :] > points[:, None, :], axis=-1), axis=1)
    sq = np.unique(points[keep], axis=0) ** 2
    X, Y = sq[:, 0], sq[:, 1]
    u, v = [1.0 / (2.0 * X)], [1.0 / (2.0 * Y)]
    i, j = np.triu_indices(len(sq), k=1)
    det = X[i] * Y[j] - X[j] * Y[i]
    ok = np.abs(det) > 1e-12
    u.append((Y[j][ok] - Y[i][ok]) / det[ok])
    v.append((X[i][ok] - X[j][ok]) / det[ok])
    u, v = np.concatenate(u), np.concatenate(v)
    # the feasible candidate of largest u v (the first such by index), checked in that order a chunk at a time: the
    # best is nearly always among the first few of the hundreds of pairs a turned car's corners make
    positive = (u > 0.0) & (v > 0.0)
    order = np.argsort(-np.where(positive, u * v, -np.inf), kind="stable")
    best = 0  # (none feasible: the first candidate, as an argmax over no feasible one gives)
    for start in range(0, len(order), _CANDIDATE_CHUNK):
        chunk = order[start:start + _CANDIDATE_CHUNK]
        feasible = positive[chunk] & np.all(np.outer(u[chunk], X) + np.outer(v[chunk], Y) <= 1.0 + 1e-9, axis=1)
        if feasible.any():
            best = int(chunk[np.argmax(feasible)])
            break
    return float(1.0 / np.sqrt(u[best])), float(1.0 / np.sqrt(v[best]))


EGO_TURN_FADE = 2.0  # [s] the ego's turned box counts in full at t = 0 and not at all from this time on


def turned_box_growth(heading, length: float, width: float, xp=np):
    """[m] (2, ...) sqrt(2) x how much the axis-aligned box around a car of ``length`` x ``width`` [m] turned by
    ``heading`` [rad] (any shape) exceeds its box along the road, longitudinally and laterally: what a collision
    ellipse's semi-axes grow by (:func:`ellipse_semi_axes` circumscribes the boxes with sqrt(2)). ``xp``: the array
    module (numpy, or jax.numpy inside a traced function)."""
    c, s = xp.abs(xp.cos(heading)), xp.abs(xp.sin(heading))
    grow_long = 0.5 * (length * c + width * s) - 0.5 * length
    grow_lat = 0.5 * (length * s + width * c) - 0.5 * width
    return math.sqrt(2.0) * xp.maximum(xp.stack([grow_long, grow_lat]), 0.0)


def ego_box_growth(ego: EgoState, t: np.ndarray) -> np.ndarray:
    """[m] (2, K) growth of every collision ellipse's longitudinal and lateral semi-axis at times ``t`` [s] because
    the ego is turned (:func:`turned_box_growth`), with its heading fading linearly from its heading now
    (:attr:`EgoState.box_heading`) to 0 by :data:`EGO_TURN_FADE`.

    At 0.28 rad the ego's front corner reaches 0.65 m further into the next lane than its side does along the
    road: in P2's dense traffic the ego crawling diagonally out of a jam touched the car ahead in the next lane,
    inside no ellipse.
    The growth fades because the plan itself turns the car back (replanning applies it again from the heading the
    car then has); held over the whole horizon it made a turned, stopped car's every plan past a neighbour
    infeasible. (A stop cannot turn the car back once it stands: :func:`driveopt.fallback.box_contact` holds it.)"""
    heading = ego.box_heading * np.clip(1.0 - np.asarray(t) / EGO_TURN_FADE, 0.0, 1.0)
    return turned_box_growth(heading, ego.length, ego.width)


BRAKING_TIME = 3.0  # [s] how long an observed braking is assumed to last in predictions


def predict_neighbour(
    n: Neighbour, t: np.ndarray, y_range: tuple[float, float], braking_time: float = BRAKING_TIME
) -> tuple[np.ndarray, np.ndarray]:
    """[m] predicted centre of a neighbour at times t [s]; y kept on the road.

    Constant velocity, except that a braking neighbour (``accel`` < 0) keeps braking for
    ``braking_time`` s (never reversing), then holds its speed: a car braking hard for a jam ahead
    of it would otherwise be predicted to keep going and the ego would react a second late.
    Acceleration is not extrapolated (a constant-velocity leader is the safer assumption).
    ``braking_time`` 0: constant velocity for every neighbour (P1).
    A neighbour with a ``lane_center`` moves across the road only until it reaches it (and holds its offset when its
    lateral rate points away from it): a car keeping its lane on a curve has a lateral rate of a tenth of a metre per
    second while its steering lags, which over a 15 s horizon would carry it 2 m to its lane's edge, and a plan that
    keeps the lane behind it would be predicted to pass it inside the lane.
    A :class:`PathNeighbour` is where its path says (not kept on the road: crossing traffic is off it before and after).
    """
    if isinstance(n, PathNeighbour):
        return np.interp(t, n.t, n.path_x), np.interp(t, n.t, n.path_y)
    speed = math.hypot(n.vx, n.vy)
    decel = -min(n.accel, 0.0)
    if decel == 0.0 or speed < 1e-6 or braking_time <= 0.0:
        return n.x + n.vx * t, _across(n, n.y + n.vy * t, y_range)
    braking = min(braking_time, speed / decel)
    tau = np.minimum(t, braking)
    distance = speed * tau - 0.5 * decel * tau**2 + (speed - decel * braking) * (t - tau)
    return n.x + n.vx / speed * distance, _across(n, n.y + n.vy / speed * distance, y_range)


def _across(n: Neighbour, y: np.ndarray, y_range: tuple[float, float]) -> np.ndarray:
    """[m] the predicted lateral positions ``y`` of ``n``, ended at its lane centre where it has one, on the road."""
    if n.lane_center is not None:
        y = np.clip(y, min(n.y, n.lane_center), max(n.y, n.lane_center))
    return np.clip(y, *y_range)


def is_follower(scene: Scene, n: Neighbour) -> bool:
    """A neighbour behind the ego in the ego's lane (it is the one that must keep its distance)."""
    return n.x < scene.ego.x and abs(n.y - scene.ego.y) < 0.5 * scene.road.lane_width


def nearest_neighbours(scene: Scene, count: int, ignore_followers: bool = False) -> list[Neighbour]:
    """The ``count`` neighbours closest to the ego (Euclidean distance now), nearest first."""
    ego = scene.ego
    candidates = [n for n in scene.neighbours if not (ignore_followers and is_follower(scene, n))]
    return sorted(candidates, key=lambda n: math.hypot(n.x - ego.x, n.y - ego.y))[:count]


SELECTION_TIME = 4.0  # [s] look-ahead of the obstacle selection (covers a comfortable stop from ~12 m/s)
_SELECTION_STEPS = 21  # [-] times at which the closest approach is evaluated


def relevant_neighbours(
    scene: Scene, count: int, ignore_followers: bool = False, lookahead: float = SELECTION_TIME,
    braking_time: float = BRAKING_TIME,
) -> list[Neighbour]:
    """The ``count`` neighbours that come closest to the ego within ``lookahead`` [s], closest first.

    The closest approach is measured between each neighbour's prediction (:func:`predict_neighbour`)
    and the ego holding its velocity, both kept on the road; ties (several cars reached) go to the
    nearer one now. ``lookahead`` 0 ranks by the distance now (:func:`nearest_neighbours`, P1).
    """
    if lookahead <= 0.0:
        return nearest_neighbours(scene, count, ignore_followers)
    ego = scene.ego
    t = np.linspace(0.0, lookahead, _SELECTION_STEPS)
    ego_x, ego_y = ego.x + ego.vx * t, np.clip(ego.y + ego.vy * t, *scene.road.edges)

    def key(n: Neighbour) -> tuple[float, float]:
        x, y = predict_neighbour(n, t, scene.road.edges, braking_time)
        return float(np.min(np.hypot(x - ego_x, y - ego_y))), math.hypot(n.x - ego.x, n.y - ego.y)

    candidates = [n for n in scene.neighbours if not (ignore_followers and is_follower(scene, n))]
    return sorted(candidates, key=key)[:count]


def obstacle_slots(scene: Scene, t: np.ndarray, count: int, ignore_followers: bool = False,
                   lookahead: float = SELECTION_TIME, braking_time: float = BRAKING_TIME,
                   ) -> list[tuple[Neighbour, np.ndarray | None]]:
    """The ``count`` obstacle slots a planning problem holds, as (neighbour, the boolean mask of the times ``t`` [s] it
    is planned against in that slot, None for all): the :func:`relevant_neighbours`, each in one slot.

    Where the scene holds crossing traffic (a :class:`PathNeighbour`, one slot per heading phase,
    :func:`path_phases`), a turning car takes several slots, and taking the nearest neighbours first would leave the
    others out (at intersection-v0 a call wants about 29 slots for 8 cars). Then every neighbour's slots are
    candidates: a phase whose ellipse never reaches the road's width at any of its times (widened by the ego's turned
    box) is left out, and the others are ranked by their closest approach, over their own times ``t``, to the ego
    holding its velocity (as :func:`relevant_neighbours` ranks neighbours within its look-ahead; ties go to the
    neighbour it ranks first)."""
    if not any(isinstance(n, PathNeighbour) for n in scene.neighbours):
        return [(n, None) for n in relevant_neighbours(scene, count, ignore_followers, lookahead, braking_time)]
    ego = scene.ego
    low, high = scene.road.edges
    ego_x, ego_y = ego.x + ego.vx * t, np.clip(ego.y + ego.vy * t, low, high)
    reach = ego_box_growth(ego, np.zeros(1))[1, 0]  # [m] the ego's turned box beyond its box along the road, across it
    ranked = []
    for rank, n in enumerate(relevant_neighbours(scene, len(scene.neighbours), ignore_followers, lookahead, braking_time)):
        for slot, nodes in path_phases(n, t) if isinstance(n, PathNeighbour) else [(n, None)]:
            x, y = predict_neighbour(slot, t, scene.road.edges, braking_time)
            on = np.ones(len(t), dtype=bool) if nodes is None else nodes
            lateral = ellipse_semi_axes(ego, slot, scene.ellipse_margin)[1] + reach
            if np.all(np.abs(y - np.clip(y, low, high))[on] >= lateral):
                continue  # beside the road all the while: its ellipse never reaches any plan
            ranked.append((float(np.min(np.hypot(x - ego_x, y - ego_y)[on])), rank, slot, nodes))
    ranked.sort(key=lambda r: r[:2])
    return [(slot, nodes) for _, _, slot, nodes in ranked[:count]]
