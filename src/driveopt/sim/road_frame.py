"""The road (Frenet) frame along the ego's route through highway-env's lane graph, and motion expressed in it.

The frame follows the lowest driving lane of each road of the route (:mod:`driveopt.sim.lane_graph`):
``s`` [m] is the arc length along that reference line and ``d`` [m] the lateral offset from it (upstream's
lateral axis: to the left of the direction of travel, +y on a road along +x). At the ego's road, ``(s, d)``
of the reference lane's start are that point's coordinates along and across the lane's initial direction,
so that on a road along +x ``s`` is the world ``x`` and ``d`` the world ``y``; the roads ahead and behind
continue the arc length. Consecutive straight, collinear roads form one piece measured in the ego road's
lane (a straight road along +x, any number of sections, is exactly today's ``x = x0 + (X - x0)``,
``y = y0 + (Y - y0)``); a curved piece (``CircularLane``, ``SineLane``) is measured in its own lane.

What the frame represents, checked whenever it is built (every perception):

- each road's driving lanes are parallel (constant lateral offset: concentric arcs, parallel lines),
  equally wide and adjacent; otherwise :class:`RoadFrameError` names the lane;
- lanes of other roads may cross the route's (an intersection's, a roundabout's): the frame follows the route
  through them, and the traffic on them is predicted along its own lanes (:mod:`driveopt.sim.crossing`; a lane
  meeting the route at more than :data:`CROSSING_ANGLE` crosses it);
- the route does not end at a junction (a node whose roads do not continue the route's lanes, or only
  by a turn sharper than :data:`driveopt.sim.lane_graph.MAX_TURN`, as into a roundabout's ring);
- the ego lies on the frame, within :data:`MAX_EGO_OFFSET` of its road's lanes.

Vehicles are placed on the piece whose longitudinal range holds them, nearest laterally; those more than
:data:`LATERAL_REACH` beside the road's lanes or beyond a curved end of the frame are dropped (the other
side of a racetrack's infield, a far part of the graph).

Upstream's kinematic bicycle (``Vehicle.step``) moves the centre along ``heading + beta`` with
``beta = arctan(tan(steering) / 2)``, not along ``heading``; ``Vehicle.velocity`` ignores ``beta`` (an
upstream TODO). :func:`vehicle_motion` uses the course ``heading + beta`` and the acceleration the vehicle
is applying (``vehicle.action``, held until its next action): tangential ``a`` and normal
``speed * heading_rate = speed**2 * sin(beta) / (length / 2)``, turned into Frenet rates
``s' = v_t / (1 - kappa d)``, ``d' = v_n`` (``kappa``: the reference line's curvature, 0 on a straight road).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Iterator, NamedTuple, Sequence

import numpy as np

from driveopt.errors import DriveoptError
from driveopt.scene import CURVATURE_CELL, CURVATURE_CELLS, Road
from driveopt.sim.corner_lane import CornerLane
from driveopt.sim.lane_graph import (
    BRANCH_DISTANCE,
    JOIN_DISTANCE,
    continued_before_start,
    continues_past_end,
    driving_lanes,
    junctions,
    lane_end,
    lane_start,
    next_road,
    previous_road,
    road_joins,
    route_roads,
    wrap_angle,
)

_GEOMETRY_TOL = 1e-6  # [m] tolerance on equal lane widths and on straight sections being collinear
_SPACING_TOL = 0.25  # [m] tolerance on adjacent lanes' spacing being their width (upstream's racetrack: 5.09 m for 5 m)
_PARALLEL_TOL = 0.1  # [m] tolerance on a lane's lateral offset being constant along its road
AHEAD = 600.0  # [m] route length the frame covers ahead of the ego (15 s at 40 m/s)
BEHIND = 150.0  # [m] route length the frame covers behind the ego
LATERAL_REACH = 15.0  # [m] vehicles further than this beside the road's lanes are not placed on the frame
CROSSING_ANGLE = math.radians(30.0)  # [rad] a lane meeting the route at a larger angle (and not oncoming) crosses it
MAX_EGO_OFFSET = 8.0  # [m] the ego further than this beside its road's lanes is not on the frame
_CURVATURE_STEP = 1.0  # [m] half-step of the numerical curvature of a sine lane, and spacing of its samples
_MAX_PIECES = 256  # [-] roads followed at most in each direction
CORNER_ANGLE = math.radians(10.0)  # [rad] where the route turns more than this from one road's lane to the next's
# (a roundabout's entry and exit), a corner piece turns the frame from one lane into the other (driveopt.sim.corner_lane)
CORNER_LENGTH = 16.0  # [m] ... over this long on the entry's or exit's side (all but _MIN_PIECE of a shorter lane) ...
RING_REACH = 5.0  # [m] ... and this far into the ring, ...
RING_ARM, ROAD_ARM = 0.5, 0.25  # [-] ... its curve's arms on the ring's side and on the other, fractions of its chord
_MIN_PIECE = 1.0  # [m] a corner leaves at least this much of the piece it reaches into
# [m] a road whose adjacent lanes are spaced wider than their width by more than this leaves a strip between them on
# no lane, which upstream counts as off the road (racetrack-v0's road ("f", "g"): 8.7 cm; a car changing lanes there
# was caught in it and the episode ended): the planner keeps the ego's lane while such a road is within its preview
LANE_GAP = 0.01
MIN_REFERENCE_RADIUS = 5.0  # [m] an arc is measured along its circle through the ego's lane only where that is wider


class RoadFrameError(DriveoptError):
    """The simulator's road cannot be represented in a Frenet frame along the ego's route."""


class Motion(NamedTuple):
    """State of a vehicle (or static object) in the road frame."""

    x: float  # [m] s, along the road
    y: float  # [m] d, across the road
    vx: float  # [m/s] s' of the centre
    vy: float  # [m/s] d'
    ax: float  # [m/s^2] s''
    ay: float  # [m/s^2] d''
    speed: float  # [m/s] upstream's ``speed`` (signed, along the course)
    heading: float  # [rad] body heading relative to the road, in [-pi, pi)
    course: float  # [rad] direction of motion of the centre relative to the road: heading + slip
    length: float  # [m]
    width: float  # [m]


def slip_angle(steering: float) -> float:
    """[rad] upstream's slip angle of the centre for a front-wheel angle [rad]: arctan(tan(steering) / 2)."""
    return math.atan(0.5 * math.tan(steering))


def _lane_types() -> Any:
    """highway-env's lane module, imported on first use: only a simulated road has lanes, and ``driveopt plan``
    (which imports this module through the registry) should not pay for importing highway-env."""
    from highway_env.road import lane

    return lane


def _is_circular(lane: Any) -> bool:
    return isinstance(lane, _lane_types().CircularLane)


def _is_straight(lane: Any) -> bool:
    types = _lane_types()
    return isinstance(lane, types.StraightLane) and not isinstance(lane, types.SineLane)


def lane_curvature(lane: Any, longitudinal: float) -> float:
    """[1/m] signed curvature of a lane's centre line at ``longitudinal`` [m] (positive: turning left, towards +d)."""
    if _is_straight(lane):
        return 0.0
    if _is_circular(lane):
        return lane.direction / lane.radius
    h = _CURVATURE_STEP
    return wrap_angle(lane.heading_at(longitudinal + h) - lane.heading_at(longitudinal - h)) / (2.0 * h)


def _name(road: tuple[str, str], lane_id: int) -> str:
    return f"lane {(road[0], road[1], lane_id)!r}"


class Band(NamedTuple):
    """The driving lanes of one road of the route, in frame coordinates."""

    road: tuple[str, str]
    s_from: float  # [m] where the road starts on the frame
    s_to: float  # [m] where it ends
    first_center: float  # [m] d of its lowest lane's centre line
    num_lanes: int
    lane_width: float  # [m]
    lane_gap: float = 0.0  # [m] the widest gap between two of its adjacent lanes (spaced wider than they are wide)

    @property
    def low(self) -> float:
        """[m] d of the right edge."""
        return self.first_center - 0.5 * self.lane_width

    @property
    def high(self) -> float:
        """[m] d of the left edge."""
        return self.first_center + (self.num_lanes - 0.5) * self.lane_width


@dataclasses.dataclass
class Piece:
    """One stretch of the frame measured in one lane: ``s = s_start + longitudinal``, ``d = d_shift + lateral``."""

    lane: Any  # the reference lane (highway-env lane object)
    s_start: float  # [m] s at the lane's longitudinal 0
    d_shift: float  # [m] d of the lane's centre line
    lo: float  # [m] longitudinal range the piece covers (collinear straight roads extend it beyond the lane)
    hi: float
    bands: list[Band]
    open_lo: bool = False  # a straight first piece extends backwards without end
    open_hi: bool = False  # a straight last piece extends forwards without end
    lo_margin: float = 0.0  # [m] it also covers this far before lo: the outside of the corner where the route enters
    # its road part-way along (lane-keeping-v0's sine road), which the piece before does not reach
    ring: bool = False  # a road whose lanes another road continues where the route joins or leaves it: a ring at an
    # entry or exit, beside its outer lane (roundabout-v0) or end to end (roundabout-generic-v0). Where the route turns
    # there by more than CORNER_ANGLE, the corner piece lies on the entry's or exit's side of the joint

    def covers(self, longitudinal: float, margin: float = 0.0) -> bool:
        return ((self.open_lo or longitudinal >= self.lo - margin - self.lo_margin)
                and (self.open_hi or longitudinal <= self.hi + margin))

    @property
    def straight(self) -> bool:
        return _is_straight(self.lane)


def _road_lanes(network: Any, road: tuple[str, str]) -> tuple[Any, list[float], float]:
    """(reference lane, lateral offsets [m] of the driving lanes from it, lane width [m]); RoadFrameError naming a
    lane that is not parallel, not as wide or not adjacent."""
    lanes = driving_lanes(network, road)
    ref_id, ref = lanes[0]
    width = float(ref.width_at(0.0))
    offsets = []
    for lane_id, lane in lanes:
        lateral = [ref.local_coordinates(np.asarray(lane.position(f * lane.length, 0.0), dtype=float))[1]
                   for f in (0.0, 0.5, 1.0)]
        if np.ptp(lateral) > _PARALLEL_TOL:
            raise RoadFrameError(f"{_name(road, lane_id)} is not parallel to {_name(road, ref_id)}: its lateral offset "
                                 f"varies from {min(lateral):.2f} to {max(lateral):.2f} m along the road")
        if abs(float(lane.width_at(0.0)) - width) > _GEOMETRY_TOL:
            raise RoadFrameError(f"{_name(road, lane_id)} is {float(lane.width_at(0.0))} m wide, {_name(road, ref_id)} "
                                 f"{width} m: driving lanes have different widths")
        offsets.append(float(lateral[0]))
    if len(offsets) > 1 and np.max(np.abs(np.diff(offsets) - width)) > _SPACING_TOL:
        raise RoadFrameError(f"driving lanes of road {road!r} centred at lateral offsets {offsets} are not adjacent "
                             f"{width} m lanes")
    return ref, offsets, width


def _collinear(piece: Piece, lane: Any, joint: np.ndarray) -> bool:
    """Whether a straight ``lane`` lies on the straight ``piece``'s line through ``joint`` (a point of both)."""
    if not (piece.straight and _is_straight(lane)):
        return False
    _, lateral = piece.lane.local_coordinates(joint)
    return abs(lateral) < _GEOMETRY_TOL and float(np.dot(piece.lane.direction, lane.direction)) > 1.0 - 1e-12


class RoadFrame:
    """The Frenet frame of the ego's route at one moment (see the module docstring)."""

    def __init__(self, pieces: list[Piece], ego_road: tuple[str, str], roads: tuple[tuple[str, str], ...],
                 ego_s: float, dead_end: tuple[str, str] | None = None) -> None:
        self.pieces = pieces
        self.ego_road = ego_road
        self.roads = roads  # every road the frame follows, in order
        self.ego_s = ego_s  # [m] about where the ego is (tells the passes of a loop apart)
        self.dead_end_road = dead_end  # the frame's last road when no road continues it (its lanes end there)

    @property
    def dead_end(self) -> Band | None:
        """The band of the frame's last road where that road is a dead end (no road continues it: the car must stop
        before ``s_to``); None where the road goes on (a loop, or beyond the frame's reach)."""
        bands = [b for p in self.pieces for b in p.bands if b.road == self.dead_end_road]
        return max(bands, key=lambda b: b.s_to) if bands else None

    # ------------------------------------------------------------------ world -> frame
    def locate(self, position: np.ndarray, near_s: float | None = None) -> tuple[float, float, Piece, float, float] | None:
        """(s, d, piece, longitudinal, lateral) of a world position [m], or None where the frame does not reach it.

        Among the pieces whose range holds it, the one it is laterally nearest to the lanes of (ties: one whose range
        holds it without its ``lo_margin`` first, then, as on a loop that the frame passes twice, the one nearest
        ``near_s``)."""
        position = np.asarray(position, dtype=float)
        best, best_key = None, None
        for piece in self.pieces:
            longitudinal, lateral = piece.lane.local_coordinates(position)
            if not piece.covers(longitudinal, margin=0.5):
                continue
            s, d = piece.s_start + longitudinal, piece.d_shift + lateral
            outside = max(min(b.low for b in piece.bands) - d, d - max(b.high for b in piece.bands), 0.0)
            if outside > LATERAL_REACH:
                continue
            corner = not piece.open_lo and longitudinal < piece.lo - 0.5  # only in a part-way join's lo_margin
            key = (round(outside, 6), corner, abs(s - near_s) if near_s is not None else 0.0)
            if best_key is None or key < best_key:
                best, best_key = (s, d, piece, float(longitudinal), float(lateral)), key
        return best

    # ------------------------------------------------------------------ along the reference line
    def piece_at(self, s: float) -> tuple[Piece, float]:
        """(piece, longitudinal [m]) at arc length ``s`` [m]; clamped to the frame's curved ends."""
        for piece in self.pieces:
            if piece.covers(s - piece.s_start):
                return piece, s - piece.s_start
        first, last = self.pieces[0], self.pieces[-1]
        if s < first.s_start + first.lo:
            return first, first.lo
        return last, last.hi

    def curve_at(self, s: float) -> tuple[float, float]:
        """([1/m] signed curvature of the reference line at ``s``, [m] the ``d`` of the piece's line it is of)."""
        piece, longitudinal = self.piece_at(s)
        return lane_curvature(piece.lane, longitudinal), piece.d_shift

    def _curved_samples(self, s_from: float, s_to: float, extra: np.ndarray = np.zeros(0)):
        """(piece, arc lengths [m], signed curvatures [1/m]) of each curved piece over [s_from, s_to], sampled every
        :data:`_CURVATURE_STEP` and at the arc lengths ``extra`` that fall on the piece."""
        for piece in self.pieces:
            lo = max(s_from - piece.s_start, piece.lo if not piece.open_lo else -math.inf)
            hi = min(s_to - piece.s_start, piece.hi if not piece.open_hi else math.inf)
            if lo > hi or piece.straight:
                continue
            along = np.linspace(lo, hi, max(2, int((hi - lo) / _CURVATURE_STEP) + 1))
            along = np.union1d(along, np.clip(extra - piece.s_start, lo, hi)) if extra.size else along
            yield piece, piece.s_start + along, np.array([lane_curvature(piece.lane, float(a)) for a in along])

    def sharpest_curve(self, s_from: float, s_to: float) -> tuple[float, float]:
        """([1/m] the signed curvature of largest magnitude of the reference line on [s_from, s_to], [m] the ``d`` of
        the piece's own line it is the curvature of); (0.0, 0.0) on straights."""
        worst, origin = 0.0, 0.0
        for piece, _, kappa in self._curved_samples(s_from, s_to):
            sharpest = kappa[np.argmax(np.abs(kappa))]
            if abs(sharpest) > abs(worst):
                worst, origin = float(sharpest), piece.d_shift
        return worst, origin

    def curvature_between(self, s_from: float, s_to: float) -> float:
        """[1/m] the signed curvature of largest magnitude of the reference line on [s_from, s_to] (0.0 on straights)."""
        return self.sharpest_curve(s_from, s_to)[0]

    def curves_ahead(self, s_from: float, s_to: float) -> list[tuple[float, float, float]]:
        """[(distance [m] from ``s_from``, signed curvature [1/m], ``d`` [m] of the line it is the curvature of)] at the
        start of each curved stretch (and at ``s_from`` when it lies on one) up to ``s_to``, sampled every
        :data:`_CURVATURE_STEP` on sine lanes."""
        curves = []
        for piece in self.pieces:
            lo = max(s_from - piece.s_start, piece.lo)
            hi = min(s_to - piece.s_start, piece.hi)
            if lo > hi or piece.straight:
                continue
            samples = [lo] if _is_circular(piece.lane) else np.arange(lo, hi + 1e-9, _CURVATURE_STEP)
            curves += [(piece.s_start + float(x) - s_from, lane_curvature(piece.lane, float(x)), piece.d_shift)
                       for x in samples]
        return curves

    def curvature_cells(self, s: float, behind: float = 0.0) -> np.ndarray:
        """[1/m] (CURVATURE_CELLS,) the signed curvature of largest magnitude of the reference line in each
        CURVATURE_CELL-long cell ahead of ``s`` [m] (:attr:`driveopt.scene.Road.curvature_ahead`), the first reaching
        back ``behind`` [m]. Each cell also takes its neighbours' values where they are sharper: a node's position is
        read in one cell, while the car's length and the plan's motion between iterations reach into the next."""
        edges = s + CURVATURE_CELL * np.arange(CURVATURE_CELLS + 1)
        edges[0] -= behind
        cells = np.zeros(CURVATURE_CELLS)
        for _, along, kappa in self._curved_samples(edges[0], edges[-1], extra=edges):  # every cell a piece reaches
            index = np.clip(np.searchsorted(edges, along, side="right") - 1, 0, CURVATURE_CELLS - 1)
            for i, k in zip(index, kappa):
                if abs(k) > abs(cells[i]):
                    cells[i] = k
        padded = np.pad(cells, 1, mode="edge")
        candidates = np.stack([cells, padded[:-2], padded[2:]])  # the sharpest of each cell and its two neighbours
        return candidates[np.argmax(np.abs(candidates), axis=0), np.arange(CURVATURE_CELLS)]

    # ------------------------------------------------------------------ measured along the ego's lane
    def along(self, d_ref: float) -> "RoadFrame":
        """The same frame (every world point keeps its ``d``) with each circular piece measured along its concentric
        circle at ``d = d_ref`` [m] (the centre of the ego's lane) instead of its road's lowest lane, and ``s``
        continued through the pieces as before. A plan that keeps that lane then moves along ``s`` at the car's own
        speed on straights and arcs alike; measured along the lowest lane, its rate jumped where a straight met an
        arc (by 1.5x five lanes' widths outside a 20 m arc: upstream's racetrack-oval-v0), which no smooth plan
        follows: the plans braked before each curve and after it. Pieces along sine lanes and corner pieces are left
        as they are, and so is an arc whose circle at ``d_ref`` is tighter than :data:`MIN_REFERENCE_RADIUS`.
        :func:`ego_frame` measures a frame through a roundabout's ring as it is: at roundabout-generic-v0 the ring
        measured along the ego's lane collided in 3 of 20 episodes against 1 (seeds 4 and 7, at the entry and the
        exit; not traced further), and at roundabout-v0 in 1 against 0."""
        pieces: list[Piece] = []
        scales: list[float] = []
        for k, piece in enumerate(self.pieces):
            lane, scale = piece.lane, 1.0
            if _is_circular(lane):
                radius = lane.radius - lane.direction * (d_ref - piece.d_shift)
                if radius >= MIN_REFERENCE_RADIUS and radius != lane.radius:
                    scale = radius / lane.radius
                    lane = _lane_types().CircularLane(
                        lane.center, radius, lane.start_phase, lane.end_phase, clockwise=lane.clockwise,
                        width=lane.width, line_types=lane.line_types, forbidden=lane.forbidden,
                        speed_limit=lane.speed_limit, priority=lane.priority)
            lo = piece.lo * scale
            if k == 0:  # the first piece starts where it did
                s_start = piece.s_start + piece.lo - lo
            else:  # each piece starts as far from the end of the one before as it did (a gap, or an overlap)
                before, after = self.pieces[k - 1], pieces[-1]
                s_start = after.s_start + after.hi + (piece.s_start + piece.lo - before.s_start - before.hi) - lo
            pieces.append(dataclasses.replace(piece, lane=lane, s_start=s_start, lo=lo, hi=piece.hi * scale,
                                              d_shift=piece.d_shift if lane is piece.lane else d_ref,
                                              lo_margin=piece.lo_margin * scale))
            scales.append(scale)

        def moved(s: float) -> float:
            """s in this frame -> s in the new one (a corner piece's bands are its neighbours', so bands move with
            the piece their s lies on, not with the piece that lists them)."""
            for old, new, scale in zip(self.pieces, pieces, scales):
                if old.s_start + old.lo - 1e-9 <= s <= old.s_start + old.hi + 1e-9:
                    return new.s_start + scale * (s - old.s_start)
            ends = [(old.s_start + old.hi, new.s_start + new.hi) for old, new in zip(self.pieces, pieces)
                    if old.s_start + old.hi < s]  # in a gap, or beyond the ends: shifted with the piece before
            if ends:
                return ends[-1][1] + s - ends[-1][0]
            first, new_first = self.pieces[0], pieces[0]
            return new_first.s_start + new_first.lo + s - first.s_start - first.lo

        for piece in pieces:
            piece.bands = [b._replace(s_from=moved(b.s_from), s_to=moved(b.s_to)) for b in piece.bands]
        return RoadFrame(pieces, self.ego_road, self.roads, moved(self.ego_s), self.dead_end_road)

    # ------------------------------------------------------------------ the planner's road
    def ego_band(self, s: float) -> Band:
        """The band of the ego's road holding ``s`` (the nearest one, on a loop)."""
        bands = [b for p in self.pieces for b in p.bands if b.road == self.ego_road]
        return min(bands, key=lambda b: max(b.s_from - s, s - b.s_to, 0.0))

    def road(self, s: float, lane_preview: float, curvature_preview: float, behind: float = 0.0,
             per_node: bool = False, d: float | None = None, gap_preview: float | None = None) -> Road:
        """The planner's :class:`Road` at ``s`` [m]: the ego road's lanes that continue over the next ``lane_preview``
        [m] (a lane that ends, or leads only off the route, is left out; only the lane nearest ``d`` [m], the ego's,
        from ``gap_preview`` [m] (default: the lane preview) before a road with a gap between its lanes
        (:data:`LANE_GAP`) to its end), and the curvature of largest
        magnitude over [s - behind, s + curvature_preview] (signed; the plan's bound at every node); ``per_node``: over
        [s - behind, s], and the curvature ahead in the cells that start within ``curvature_preview``
        (:meth:`curvature_cells`; zero in the others, and none at all where it is straight). The curvature's origin is
        the ``d`` of the line of the sharpest curve within the preview (every cell's, with ``per_node``: exact while
        the route's pieces share their reference lines, as a racetrack's do)."""
        ego = self.ego_band(s)
        k_lo, k_hi = 0, ego.num_lanes - 1
        gapped = ego.lane_gap > LANE_GAP
        gap_preview = lane_preview if gap_preview is None else gap_preview
        for piece in self.pieces:
            for band in piece.bands:
                if band is ego or band.s_to < s:
                    continue
                gapped = gapped or (band.lane_gap > LANE_GAP and band.s_from <= s + gap_preview)
                if band.s_from > s + lane_preview:
                    continue
                tol = 0.5 * abs(band.lane_width - ego.lane_width) + 0.5
                inside = [k for k in range(ego.num_lanes)
                          if band.first_center - tol <= ego.first_center + k * ego.lane_width
                          <= band.first_center + (band.num_lanes - 1) * band.lane_width + tol]
                if inside:  # a road that shares no lane with the ego's (a shifted section) leaves the lanes as they are
                    k_lo, k_hi = max(k_lo, inside[0]), min(k_hi, inside[-1])
        if k_hi < k_lo:
            k_lo, k_hi = 0, ego.num_lanes - 1
        if gapped and d is not None:
            k_lo = k_hi = int(np.clip(round((d - ego.first_center) / ego.lane_width), k_lo, k_hi))
        ahead = np.zeros(0)
        if per_node:
            ahead = self.curvature_cells(s, behind)
            ahead[CURVATURE_CELL * np.arange(CURVATURE_CELLS) > curvature_preview] = 0.0
        curvature, origin = self.sharpest_curve(s - behind, s + curvature_preview)
        if per_node:
            curvature = self.curvature_between(s - behind, s)
        return Road(num_lanes=k_hi - k_lo + 1, lane_width=ego.lane_width,
                    first_lane_center=ego.first_center + k_lo * ego.lane_width, curvature=curvature,
                    curvature_ahead=tuple(ahead) if ahead.any() else (),  # a straight road's, exactly
                    curvature_origin=origin)

    # ------------------------------------------------------------------ frame -> world
    def to_world(self, s: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, ...]:
        """(X, Y [m], heading of the reference line [rad], its curvature [1/m], offset from it [m]) at arc lengths
        ``s`` [m] and offsets ``d`` [m], each shaped (N,)."""
        out = np.empty((5, np.size(s)))
        for i, (si, di) in enumerate(zip(np.ravel(s), np.ravel(d))):
            piece, longitudinal = self.piece_at(float(si))
            lateral = float(di) - piece.d_shift
            x, y = piece.lane.position(longitudinal, lateral)
            out[:, i] = x, y, piece.lane.heading_at(longitudinal), lane_curvature(piece.lane, longitudinal), lateral
        return tuple(out)


# ---------------------------------------------------------------------- building the frame
def _bands_of(network: Any, piece: Piece, road: tuple[str, str], s_from: float, s_to: float) -> Band:
    ref, offsets, width = _road_lanes(network, road)
    lateral = piece.lane.local_coordinates(lane_start(ref))[1] if ref is not piece.lane else 0.0
    gap = max(np.diff(offsets).max() - width, 0.0) if len(offsets) > 1 else 0.0
    return Band(road, s_from, s_to, piece.d_shift + lateral, len(offsets), width, float(gap))


def _origin(lane: Any) -> tuple[float, float]:
    """(s, d) [m] of a lane's start: its coordinates along and across the lane's initial direction."""
    start = lane_start(lane)
    heading = float(lane.heading_at(0.0))
    c, s = math.cos(heading), math.sin(heading)
    return float(start[0] * c + start[1] * s), float(-start[0] * s + start[1] * c)


def _entry(network: Any, road: tuple[str, str], ref: Any, following: tuple[str, str], nxt: Any) -> float:
    """[m] along ``following``'s reference lane ``nxt`` where the route from ``road`` (reference lane ``ref``) joins it:
    0.0 where it starts there, more on a road joined part-way along (:func:`~driveopt.sim.lane_graph.road_joins`)."""
    return next((at for lane, joined, at in road_joins(network, road, following) if lane is ref and joined is nxt), 0.0)


def _aligned(network: Any, ring: tuple[str, str], lateral: float) -> float:
    """[m] lateral offset, from the reference lane of road ``ring``, of its lane centre nearest ``lateral`` [m] (where an
    entry ends or an exit starts beside the ring: upstream's roundabout-v0 2.1 m outside the outer lane's centre), when
    within one lane's width; else ``lateral``. The frame puts the entry's or exit's lane on that lane's centre line
    (the two lanes' maps then differ at the joint by that gap, which the corner piece between them closes), so the
    planner's lanes continue across the joint as the lane graph joins them."""
    _, offsets, width = _road_lanes(network, ring)
    nearest = min(offsets, key=lambda offset: abs(offset - lateral))
    return nearest if abs(nearest - lateral) <= width else lateral


def _corner(before: Any, after: Any, entry: float, band: Band) -> float:
    """[m] how far before ``entry`` [m] a piece along lane ``after`` reaches to cover the outside of the corner where
    lane ``before`` ends on it part-way along: the road's width and :data:`MAX_EGO_OFFSET` beside it, times the tangent
    of the change of heading there."""
    turn = abs(wrap_angle(after.heading_at(entry) - before.heading_at(before.length)))
    return (band.num_lanes * band.lane_width + MAX_EGO_OFFSET) * math.tan(turn)


def build_frame(network: Any, ego_road: tuple[str, str], route: Sequence[Any] | None = None, *,
                ahead: float = AHEAD, behind: float = BEHIND, ego_longitudinal: float = 0.0) -> RoadFrame:
    """The frame along the route through ``ego_road`` (see the module docstring); ``ego_longitudinal`` [m]: the ego's
    position along its road's reference lane, from which ``ahead`` and ``behind`` [m] are measured."""
    planned = route_roads(route)
    ref, _, _ = _road_lanes(network, ego_road)
    s0, d0 = _origin(ref)
    first = Piece(ref, s0, d0, 0.0, float(ref.length), [])
    first.bands.append(_bands_of(network, first, ego_road, s0, s0 + float(ref.length)))
    pieces, roads = [first], [ego_road]

    # Forwards. A road the route enters part-way along (lane-keeping-v0's sine road) starts on the frame there.
    road, road_ref, left = ego_road, ref, ahead - (float(ref.length) - ego_longitudinal)
    dead_end = None
    for _ in range(_MAX_PIECES):
        following = next_road(network, road, planned)
        last = pieces[-1]
        if following is None:
            arms = junctions(network, road)
            if arms:
                joined, turn = arms[0]
                how = (f"by turning {math.degrees(turn):.0f} deg" if turn is not None
                       else "on lanes that do not start where its lanes end")
                raise RoadFrameError(f"the route's road {road!r} ends at node {road[1]!r}, where it continues only {how} "
                                     f"onto road {joined!r}: a junction (an intersection's, a roundabout's) cannot be "
                                     "followed in a Frenet frame along the route; driveopt drives roads whose lanes "
                                     "continue one another (straight, curved, merging, oncoming)")
            last.open_hi = last.straight
            dead_end = road
            break
        if left <= 0.0:
            break
        nxt, _, _ = _road_lanes(network, following)
        entry = _entry(network, road, road_ref, following, nxt)  # [m] along nxt where the route joins it
        joint = np.asarray(nxt.position(entry, 0.0), dtype=float)
        if not entry and _collinear(last, nxt, joint):
            s_from = last.s_start + last.hi
            last.hi += float(nxt.length)
            last.bands.append(_bands_of(network, last, following, s_from, last.s_start + last.hi))
        else:
            longitudinal, lateral = last.lane.local_coordinates(joint)
            length = float(nxt.length)
            offset = not entry and float(longitudinal) - last.hi > JOIN_DISTANCE  # it starts past this end, beside it
            if offset and continues_past_end(network, road):  # a ring's exit: the ring's lanes reach its start
                last.hi = float(longitudinal)
                last.bands[-1] = last.bands[-1]._replace(s_to=last.s_start + last.hi)
                last.ring = True
                piece = Piece(nxt, last.s_start + last.hi, last.d_shift + _aligned(network, road, float(lateral)), 0.0,
                              length, [])
            elif offset and continued_before_start(network, following):  # a ring's entry: the ring reaches back to it
                back, across = nxt.local_coordinates(np.asarray(last.lane.position(last.hi, 0.0), dtype=float))
                piece = Piece(nxt, last.s_start + last.hi - float(back),
                              last.d_shift - _aligned(network, following, float(across)), float(back), length, [],
                              ring=True)
            else:
                piece = Piece(nxt, last.s_start + last.hi - entry, last.d_shift + float(lateral), entry, length, [])
                if not entry:  # end to end, as at roundabout-generic-v0's ring (at an angle): a ring's exit or entry?
                    last.ring = last.ring or continues_past_end(network, road, other_than=following)
                    piece.ring = continued_before_start(network, following, other_than=road)
            piece.bands.append(_bands_of(network, piece, following, piece.s_start + piece.lo, piece.s_start + piece.hi))
            if entry:
                piece.lo_margin = _corner(road_ref, nxt, entry, piece.bands[0])
            pieces.append(piece)
        left -= float(nxt.length) - entry
        road, road_ref = following, nxt
        roads.append(road)
    else:
        pieces[-1].open_hi = pieces[-1].straight

    # Backwards.
    road, road_ref, left = ego_road, ref, behind - ego_longitudinal
    for _ in range(_MAX_PIECES):
        preceding = previous_road(network, road, planned)
        head = pieces[0]
        if preceding is None:
            head.open_lo = head.straight
            break
        if left <= 0.0:
            break
        prev, _, _ = _road_lanes(network, preceding)
        joint = lane_end(prev)
        entry = _entry(network, preceding, prev, road, road_ref)
        if entry:  # the route enters ``road`` part-way along: the frame starts on it there
            head.lo = float(head.lane.local_coordinates(joint)[0])
            head.bands[0] = head.bands[0]._replace(s_from=head.s_start + head.lo)
            head.lo_margin = _corner(prev, road_ref, entry, head.bands[0])
        if not entry and _collinear(head, prev, joint):
            s_to = head.s_start + head.lo
            head.lo -= float(prev.length)
            head.bands.insert(0, _bands_of(network, head, preceding, head.s_start + head.lo, s_to))
        else:
            longitudinal, lateral = head.lane.local_coordinates(joint)
            length = float(prev.length)
            offset = head.lo - float(longitudinal) > JOIN_DISTANCE  # the road ends short of this one's start, beside it
            if offset and continued_before_start(network, road):  # a ring seen from its entry: the ring reaches back
                head.lo = float(longitudinal)
                head.bands[0] = head.bands[0]._replace(s_from=head.s_start + head.lo)
                head.ring = True
                piece = Piece(prev, head.s_start + head.lo - length, head.d_shift + _aligned(network, road, float(lateral)),
                              0.0, length, [])
            elif offset and continues_past_end(network, preceding):  # an exit's ring: its lanes reach the exit's start
                ahead_, across = prev.local_coordinates(np.asarray(head.lane.position(head.lo, 0.0), dtype=float))
                piece = Piece(prev, head.s_start + head.lo - float(ahead_),
                              head.d_shift - _aligned(network, preceding, float(across)), 0.0, float(ahead_), [],
                              ring=True)
            else:
                piece = Piece(prev, head.s_start + head.lo - length, head.d_shift + float(lateral), 0.0, length, [])
                if not entry:  # end to end: a ring's entry or exit?
                    head.ring = head.ring or continued_before_start(network, road, other_than=preceding)
                    piece.ring = continues_past_end(network, preceding, other_than=road)
            piece.bands.append(_bands_of(network, piece, preceding, piece.s_start, piece.s_start + piece.hi))
            pieces.insert(0, piece)
        left -= float(prev.length)
        road, road_ref = preceding, prev
        roads.insert(0, road)
    else:
        pieces[0].open_lo = pieces[0].straight

    return RoadFrame(_corners(_merge_arcs(pieces)), ego_road, tuple(roads), s0 + ego_longitudinal, dead_end)


def _continues(piece: Piece, nxt: Piece) -> bool:
    """Whether ``nxt`` lies on ``piece``'s circle, its frame coordinates those of ``piece``'s lane there, within the
    half-turn around ``piece``'s lane start that its local coordinates cover (consecutive arcs of a ring)."""
    if not (_is_circular(piece.lane) and _is_circular(nxt.lane)) or nxt.lo_margin:
        return False
    reach = 0.9 * math.pi * float(piece.lane.radius)
    if nxt.s_start + nxt.hi - piece.s_start > reach or piece.lo < -reach:
        return False
    for longitudinal in (nxt.lo, nxt.hi):
        for lateral in (0.0, 1.0):
            along, across = piece.lane.local_coordinates(np.asarray(nxt.lane.position(longitudinal, lateral), dtype=float))
            if (abs(piece.s_start + along - nxt.s_start - longitudinal) > _GEOMETRY_TOL
                    or abs(piece.d_shift + across - nxt.d_shift - lateral) > _GEOMETRY_TOL):
                return False
    return True


def _merge_arcs(pieces: list[Piece]) -> list[Piece]:
    """Consecutive pieces on one circle as one piece (the map is the same; a corner after them can then reach
    over more than one short arc)."""
    merged = [pieces[0]]
    for piece in pieces[1:]:
        last = merged[-1]
        if _continues(last, piece):
            last.hi = piece.s_start + piece.hi - last.s_start
            last.bands.extend(piece.bands)
            last.open_hi = piece.open_hi
            last.ring = last.ring or piece.ring
        else:
            merged.append(piece)
    return merged


def _reach(piece: Piece, length: float) -> float:
    """[m] how far a corner piece reaches into ``piece`` from its joint: ``length`` [m], leaving at least
    :data:`_MIN_PIECE` of a piece with ends."""
    if piece.open_lo or piece.open_hi:
        return length
    return max(min(length, piece.hi - piece.lo - _MIN_PIECE), 0.0)


def _corners(pieces: list[Piece]) -> list[Piece]:
    """The pieces with a corner piece (:class:`~driveopt.sim.corner_lane.CornerLane`) at each ring's entry or exit
    where the reference line turns by more than :data:`CORNER_ANGLE`: :data:`CORNER_LENGTH` on the entry's or exit's
    side of the joint and :data:`RING_REACH` into the ring, its reference line the entry's or exit's lane (which
    :func:`_aligned` put on a ring lane's centre line), its curve's arms :data:`RING_ARM` on the ring's side and
    :data:`ROAD_ARM` on the other, which moves the turn off the ring. A corner swings wide of both lanes; reaching further
    into the ring would take it off the ring's outer edge. The three constants keep a car within 0.9 m of the corner's
    reference line on the road (upstream's check: inside its closest lane) at roundabout-v0 and roundabout-generic-v0,
    with the sharpest curvature found (0.083 and 0.060 1/m against 0.129 and 0.091 with 4 m and arms of a third: the
    centripetal bound's speed there 9.2 m/s against 7.4 at 7 m/s^2; 6 m of the ring and arms of 0.5 and 0.2 leave
    0.064 1/m at roundabout-v0, but 0.3 m off the road 0.9 m outside the line, and a car left the road there)."""
    out = [pieces[0]]
    for piece in pieces[1:]:
        last = out[-1]
        turn = wrap_angle(float(piece.lane.heading_at(piece.lo)) - float(last.lane.heading_at(last.hi)))
        if abs(turn) <= CORNER_ANGLE or not (last.ring or piece.ring):
            out.append(piece)
            continue
        if last.ring:
            before, after, d_shift = _reach(last, RING_REACH), _reach(piece, CORNER_LENGTH), piece.d_shift
            arms = (RING_ARM, ROAD_ARM)
        else:
            before, after, d_shift = _reach(last, CORNER_LENGTH), _reach(piece, RING_REACH), last.d_shift
            arms = (ROAD_ARM, RING_ARM)
        start = last.s_start + last.hi - before
        lane = CornerLane(last.lane, start - last.s_start, d_shift - last.d_shift,
                          piece.lane, start - piece.s_start, d_shift - piece.d_shift, before + after, arms)
        out.append(Piece(lane, start, d_shift, 0.0, before + after, [last.bands[-1], piece.bands[0]]))
        last.hi -= before
        piece.lo += after
        out.append(piece)
    return out


# ---------------------------------------------------------------------- vehicles in the frame
def vehicle_motion(obj: Any, frame: RoadFrame, near_s: float | None = None) -> Motion | None:
    """Frame state of a highway-env vehicle or road object (objects without ``action`` are unaccelerated); None when
    the frame does not reach it."""
    found = frame.locate(obj.position, near_s)
    if found is None:
        return None
    x, y, piece, longitudinal, lateral = found
    heading = wrap_angle(float(obj.heading) - piece.lane.heading_at(longitudinal))
    speed = float(obj.speed)
    length, width = float(obj.LENGTH), float(obj.WIDTH)
    action = getattr(obj, "action", None)
    if isinstance(action, dict):
        beta = slip_angle(float(action.get("steering", 0.0)))
        a_t = float(action.get("acceleration", 0.0))
        a_n = speed * speed * math.sin(beta) / (0.5 * length)
    else:
        beta, a_t, a_n = 0.0, 0.0, 0.0
    kappa = lane_curvature(piece.lane, longitudinal)
    s_dot, d_dot, s_ddot, d_ddot, course = frame_rates(heading, speed, beta, a_t, a_n, kappa, lateral)
    return Motion(x=x, y=y, vx=s_dot, vy=d_dot, ax=s_ddot, ay=d_ddot, speed=speed, heading=heading, course=course,
                  length=length, width=width)


def frame_rates(heading: float, speed: float, beta: float, a_t: float, a_n: float, kappa: float,
                lateral: float) -> tuple[float, float, float, float, float]:
    """(s' [m/s], d' [m/s], s'' [m/s^2], d'' [m/s^2], course [rad]) of a bicycle's centre moving at ``speed`` [m/s]
    along ``heading + beta`` [rad] (body heading relative to the reference line, slip angle), accelerating ``a_t``
    along its course and ``a_n`` across it [m/s^2], ``lateral`` [m] beside a reference line of curvature ``kappa``
    [1/m] (the change of curvature along the line neglected); no highway-env object needed."""
    course = wrap_angle(heading + beta)
    c, s = math.cos(course), math.sin(course)
    scale = 1.0 - kappa * lateral  # s' = v_t / (1 - kappa d)
    v_t, v_n = speed * c, speed * s  # velocity along and across the reference line
    a_along, a_across = a_t * c - a_n * s, a_t * s + a_n * c
    s_dot = v_t / scale
    turn_rate = kappa * s_dot  # [rad/s] rate of the reference line's heading at the vehicle
    return s_dot, v_n, (a_along + turn_rate * v_n + kappa * v_n * s_dot) / scale, a_across - turn_rate * v_t, course


def _on_lanes(network: Any, road: tuple[str, str], position: np.ndarray, before: float = 0.0,
              past: float = 0.0) -> bool:
    """Whether ``position`` lies on one of ``road``'s driving lanes (within its length, or up to ``before`` [m] short of
    its start or ``past`` [m] beyond its end, and half its width)."""
    for _, lane in driving_lanes(network, road):
        longitudinal, lateral = lane.local_coordinates(position)
        if (-before <= longitudinal <= float(lane.length) + past
                and abs(lateral) <= 0.5 * float(lane.width_at(longitudinal))):
            return True
    return False


def _ego_roads(network: Any, ego: Any, planned: Sequence[tuple[str, str]]) -> Iterator[tuple[str, str]]:
    """The roads the frame may start from, best first: the ego's lane's road (the simulator's closest lane) where the
    ego is on its lanes and it is on the route (or there is none). Then the roads of the route whose lanes the ego is
    on: from the same node first, up to :data:`BRANCH_DISTANCE` short of its start (where a junction's branches start
    together, as an intersection's turns and straight on, the closest lane may be another branch than the one the car
    follows, and a roundabout's exit starts a few metres past the ring's lane the car leaves by); then any, up to that
    short of its start or past its end (on a roundabout's corner, :data:`CORNER_LENGTH`, the closest lane is the ring's
    lane on past the exit or before the entry, and a frame along it leaves the route there). Then, off the closest
    lane's road, any road whose lanes the ego is on (upstream's closest lane can be a sine lane far away, as
    roundabout-v0's entry when the car is on the far side of the ring); last the closest lane's road (a car just past
    a split it did not take is on it, beside a route road's end whose frame leads on along the branch it left)."""
    road = (ego.lane_index[0], ego.lane_index[1])
    position = np.asarray(ego.position, dtype=float)
    on_road = _on_lanes(network, road, position)
    if on_road and (not planned or road in planned):
        yield road
    yield from (branch for branch in planned
                if branch[0] == road[0] and _on_lanes(network, branch, position, before=BRANCH_DISTANCE))
    yield from (candidate for candidate in planned
                if _on_lanes(network, candidate, position, before=BRANCH_DISTANCE, past=BRANCH_DISTANCE))
    if not on_road:
        yield from (candidate for candidate in ((frm, to) for frm, tos in network.graph.items() for to in tos)
                    if _on_lanes(network, candidate, position))
    yield road


def ego_frame(env: Any, route: Sequence[Any] | None = None) -> tuple[RoadFrame, Motion]:
    """(the frame along the ego's route, the ego's motion in it), from the first road of :func:`_ego_roads` whose
    frame holds the ego; RoadFrameError (naming the first) when none does."""
    sim = env.unwrapped
    ego = sim.vehicle
    network = sim.road.network
    if route is None:
        route = getattr(ego, "route", None)
    tried: list[tuple[str, str]] = []
    for road in _ego_roads(network, ego, route_roads(route)):
        if road not in tried:
            tried.append(road)
            held = _frame_holding_ego(network, ego, road, route)
            if held is not None:
                return held
    raise RoadFrameError(f"the ego at {np.round(np.asarray(ego.position, dtype=float), 2).tolist()} is more than "
                         f"{MAX_EGO_OFFSET} m from the lanes of road {tried[0]!r} (its nearest lane "
                         f"{ego.lane_index!r}): it is not on the road the frame represents")


def _frame_holding_ego(network: Any, ego: Any, road: tuple[str, str], route: Sequence[Any] | None
                       ) -> tuple[RoadFrame, Motion] | None:
    """(the frame from ``road`` along ``route``, the ego's motion in it), or None where the ego is more than
    :data:`MAX_EGO_OFFSET` beside the frame's lanes."""
    ref, _, _ = _road_lanes(network, road)
    longitudinal = float(ref.local_coordinates(np.asarray(ego.position, dtype=float))[0])
    frame = build_frame(network, road, route, ego_longitudinal=longitudinal)
    me = vehicle_motion(ego, frame, near_s=frame.ego_s)
    band = frame.ego_band(me.x) if me is not None else None
    ring = any(piece.ring and _is_circular(piece.lane) for piece in frame.pieces)  # a roundabout's ring
    if band is not None and not ring:  # measured along the centre of the ego's lane (RoadFrame.along)
        lane = min(max(round((me.y - band.first_center) / band.lane_width), 0), band.num_lanes - 1)
        frame = frame.along(band.first_center + lane * band.lane_width)
        me = vehicle_motion(ego, frame, near_s=frame.ego_s)
        band = frame.ego_band(me.x) if me is not None else None
    if band is None or max(band.low - me.y, me.y - band.high) > MAX_EGO_OFFSET:
        return None
    return frame, me
