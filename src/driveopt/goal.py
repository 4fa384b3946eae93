"""Where a plan should lead: :class:`Goal`, an acceptable lateral band (or lanes), a longitudinal range, a speed window
and a time window, and what the planner makes of it.

A goal is given in the road (Frenet) frame of :mod:`driveopt.scene` (``x`` along the road, ``y`` across it) and the
episode's clock; it knows nothing of where it came from (a CommonRoad planning problem, a highway-env route's lanes at
a split), so any road source can fill it in. :func:`driveopt.problem.build_problem` takes one (``goal=``, ``time=``):

- lateral: once the goal's start is within reach (:meth:`Goal.is_near`: ``lead_time`` at the current speed, at least
  ``lead_distance``), the ego centre's bounds ``y_lb, y_ub`` become the acceptable band nearest the ego (inset by
  ``inset``) within the road's bounds, so every sample and every projected plan heads into that band (unless a slow
  neighbour in the band is still to be passed before the goal: :meth:`Goal.blocked`), and the band is the one lane
  that lane centring and the sampler's lane choices see (:meth:`Goal.lanes`); a car outside
  it is brought in by the projection's off-road recovery (``projection.recovery_time``). A band the road does not
  overlap leaves the road's bounds.
- widening (``widen`` > 0, a route's lanes at a split): before the goal's start each band reaches ``widen`` metres
  further to each side per metre still to go, so that a band far ahead accepts every lane from which it can still be
  reached by lane changes, and narrows to the band itself at the goal's start; the lane terms then see the road's
  lanes inside the bounds from the ego's own lane towards the band, so that lane centring keeps the car in a lane
  (never between two) while the ``route`` cost term draws it towards the band and the bounds require it only as late
  as it can still be reached. The bounds never exclude the ego's position or its lane's centre: they keep the car
  from moving away from the band, never push it across a lane it cannot enter yet (a car beside it there made every
  plan infeasible and the stop swerve into that car); a split that can no longer be reached is the road source's to
  give up (:func:`driveopt.sim.route_goal.missed`).
- speed: ``v_des`` clipped into the speed window, then into the speeds that arrive in the goal's range within the time
  window (fast enough to reach its start before the window closes, from the car's speed now: a car slower than the
  average speed that needs aims at the end speed of a steady acceleration that averages it; slow enough not to pass
  its end before the window opens).

No goal (``goal=None``) leaves ``build_problem`` exactly as without this module.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any, Sequence

from driveopt.scene import ProblemError, Road, Scene


def _range(name: str, value: Any, low: float = -math.inf) -> tuple[float, float] | None:
    """``value`` as a (low, high) pair of finite floats with low <= high and low >= ``low``; None stays None."""
    if value is None:
        return None
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != 2:
        raise ProblemError(f"goal.{name} must be a (low, high) pair, got {value!r}")
    pair = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(float(v)):
            raise ProblemError(f"goal.{name} must hold finite numbers, got {value!r}")
        pair.append(float(v))
    if pair[0] > pair[1]:
        raise ProblemError(f"goal.{name} must have low <= high, got {value!r}")
    if pair[0] < low:
        raise ProblemError(f"goal.{name} must be >= {low:g}, got {value!r}")
    return pair[0], pair[1]


@dataclass(frozen=True)
class Goal:
    """A goal in the road frame; every field optional (a field left empty accepts anything)."""

    bands: tuple[tuple[float, float], ...] = ()  # [m] lateral ranges of the ego centre (road-frame y) accepted at the goal
    x: tuple[float, float] | None = None  # [m] road-frame x range of the goal (start, end); None: anywhere along the road
    speed: tuple[float, float] | None = None  # [m/s] speed window at the goal
    time: tuple[float, float] | None = None  # [s] episode-time window in which the goal must be reached
    lead_time: float = 6.0  # [s] the band is imposed once the goal's start is this close at the current speed
    lead_distance: float = 40.0  # [m] ... or this close, whichever is farther
    inset: float = 0.3  # [m] the bounds keep the ego centre this far inside the band (less when the band is narrower)
    block_speed: float = 2.0  # [m/s] a neighbour in the band this much slower than v_des, not yet passed, defers the band
    widen: float = 0.0  # [m/m] before x's start each band widens on both sides by this per metre still to go (0: as given)

    def __post_init__(self) -> None:
        if isinstance(self.bands, (str, bytes)) or not isinstance(self.bands, Sequence):
            raise ProblemError(f"goal.bands must be a sequence of (low, high) pairs, got {self.bands!r}")
        object.__setattr__(self, "bands", tuple(_range(f"bands[{i}]", b) for i, b in enumerate(self.bands)))
        object.__setattr__(self, "x", _range("x", self.x))
        object.__setattr__(self, "speed", _range("speed", self.speed, 0.0))
        object.__setattr__(self, "time", _range("time", self.time))
        for name in ("lead_time", "lead_distance", "inset", "block_speed", "widen"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or not 0.0 <= float(value) < 1e4:
                raise ProblemError(f"goal.{name} must be a number in [0, 1e4), got {value!r}")
            object.__setattr__(self, name, float(value))

    @classmethod
    def in_lanes(cls, road: Road, lanes: Sequence[int], **fields: Any) -> "Goal":
        """A goal whose bands are lanes of ``road`` (indices from its first lane): a lane's band holds the centres of
        cars in it, its centre +- half a lane width. ProblemError for an index the road does not have."""
        if isinstance(lanes, (str, bytes)) or not isinstance(lanes, Sequence) or not lanes:
            raise ProblemError(f"goal lanes must be a non-empty sequence of lane indices, got {lanes!r}")
        bad = [i for i in lanes if isinstance(i, bool) or not isinstance(i, numbers.Integral) or not 0 <= i < road.num_lanes]
        if bad:
            raise ProblemError(f"goal lanes {bad} are not lanes of the road (0 to {road.num_lanes - 1})")
        half = 0.5 * road.lane_width
        return cls(bands=tuple((float(road.lane_centers[i]) - half, float(road.lane_centers[i]) + half) for i in lanes),
                   **fields)

    def is_near(self, scene: Scene) -> bool:
        """Whether the goal's start is within ``max(lead_distance, lead_time * speed)`` of the ego (always, without
        an x range)."""
        if self.x is None:
            return True
        return self.x[0] - scene.ego.x <= max(self.lead_distance, self.lead_time * abs(scene.ego.vx))

    def target_band(self, scene: Scene) -> tuple[float, float] | None:
        """[m] the acceptable band nearest the ego centre that overlaps the road's bounds, as (low, high) of the ego
        centre within them and inset by up to ``inset``; None without bands or when no band overlaps the road. With
        ``widen``, each band first widened by ``widen`` times the distance [m] still to the goal's start."""
        y_lb, y_ub = scene.lateral_bounds
        grow = self.widen * max(self.x[0] - scene.ego.x, 0.0) if self.widen > 0.0 and self.x is not None else 0.0
        best = None
        for low, high in self.bands:
            low, high = max(low - grow, y_lb), min(high + grow, y_ub)
            if low > high:
                continue
            inset = min(self.inset, 0.25 * (high - low))
            band = (low + inset, high - inset)
            y = scene.ego.y
            distance = 0.0 if band[0] <= y <= band[1] else min(abs(y - band[0]), abs(y - band[1]))
            if best is None or distance < best[0]:
                best = (distance, band)
        return None if best is None else best[1]

    def blocked(self, scene: Scene, band: tuple[float, float]) -> bool:
        """Whether a neighbour slower than ``scene.v_des`` by more than ``block_speed`` sits in ``band`` (its box
        overlapping it) between the ego, not yet passed, and the goal's end: the ego may then pass it in another lane
        first, so the band is not imposed yet."""
        end = math.inf if self.x is None else self.x[1]
        for n in scene.neighbours:
            half_length, half_width = n.half_extents
            overlaps = n.y + half_width > band[0] and n.y - half_width < band[1]
            not_passed = n.x + half_length + 0.5 * scene.ego.length > scene.ego.x
            if overlaps and not_passed and n.x - half_length < end and n.vx < scene.v_des - self.block_speed:
                return True
        return False

    def lateral_bounds(self, scene: Scene) -> tuple[float, float]:
        """[m] (y_lb, y_ub) of the ego centre: the target band once the goal is near and the band is not
        :meth:`blocked`, else the road's; a widened goal's band stretched to hold the ego centre and its lane's centre
        (see the module docstring)."""
        band = self.target_band(scene) if self.bands and self.is_near(scene) else None
        if band is None or not band[0] < band[1] or self.blocked(scene, band):
            return scene.lateral_bounds
        if self.widen > 0.0:
            _, own, _ = self._toward_band(scene)
            return min(band[0], own, scene.ego.y), max(band[1], own, scene.ego.y)
        return band

    def _toward_band(self, scene: Scene) -> tuple[list[float], float, tuple[float, float]]:
        """(the road's lane centres, the centre of the ego's lane, the band nearest the ego) [m]."""
        centres = [float(c) for c in scene.road.lane_centers]
        own = min(centres, key=lambda c: abs(c - scene.ego.y))
        band = min(self.bands, key=lambda b: max(b[0] - scene.ego.y, scene.ego.y - b[1], 0.0))
        return centres, own, band

    def lanes(self, scene: Scene, bounds: tuple[float, float]) -> tuple[float, float, int]:
        """(lane_center0 [m], lane_width [m], num_lanes) the planner's lane terms see: the road's lanes, or, once the
        band is imposed (``bounds`` differ from the road's), the band as the one lane, so that lane centring and the
        sampler's lane choices lead into it instead of to the nearest lane outside it. A widened goal (``widen``): the
        road's lanes within the bounds from the ego's own lane towards the nearest band and the band's own, so that
        lane centring keeps the car centred in its lane or one of those towards the band (never between two) and the
        sampler chooses among those lanes; :meth:`pull_band` draws it towards the band, while the bounds require the
        band only as late as it can still be reached."""
        road = scene.road
        if bounds == scene.lateral_bounds:
            return road.first_lane_center, road.lane_width, road.num_lanes
        if self.widen > 0.0:
            centres, own, (low, high) = self._toward_band(scene)
            target = min(max(own, low), high)  # [m] where the nearest band begins as seen from the ego's lane
            inside = [k for k, c in enumerate(centres) if bounds[0] - 1e-6 <= c <= bounds[1] + 1e-6
                      and (min(own, target) - 1e-6 <= c <= max(own, target) + 1e-6 or low <= c <= high)]
            if inside:
                return centres[inside[0]], road.lane_width, inside[-1] - inside[0] + 1
        return 0.5 * (bounds[0] + bounds[1]), max(bounds[1] - bounds[0], 0.5), 1

    def pull_band(self, scene: Scene, bounds: tuple[float, float]) -> tuple[float, float] | None:
        """[m] (low, high) of the ego centre that the planner's ``route`` cost term draws plans towards: for a widened
        goal near enough to bound the plan (``bounds`` other than the road's), the centres of the nearest band's lanes
        (the band inset by half a lane width; its middle when narrower than a lane); else None."""
        if self.widen <= 0.0 or bounds == scene.lateral_bounds or not self.bands:
            return None
        _, _, (low, high) = self._toward_band(scene)
        half = 0.5 * scene.road.lane_width
        return (low + half, high - half) if high - low >= 2.0 * half else (0.5 * (low + high),) * 2

    def desired_speed(self, scene: Scene, time: float = 0.0) -> float:
        """[m/s] ``scene.v_des`` within the speed window, then within the speeds that reach the goal's x range inside
        its time window from x at ``time`` [s] (the timing wins where the two disagree): at least the average speed
        that reaches its start in time, or, for an ego slower than that average now, ``2 * average - speed``, the end
        speed of a steady acceleration from its speed that covers the distance in time."""
        v = scene.v_des
        if self.speed is not None:
            v = min(max(v, self.speed[0]), self.speed[1])
        if self.time is not None and self.x is not None:
            start, end = self.x[0] - scene.ego.x, self.x[1] - scene.ego.x  # [m] to the range's start and end
            opens, closes = self.time[0] - time, self.time[1] - time  # [s] until the window opens and closes
            if closes > 0.0 and start > 0.0:
                # reach the start before the window closes: at the average speed that needs, or, from a slower car, at
                # the end speed of a steady acceleration from its speed that covers the distance in time (the car
                # must go faster than the average later for the time it spends slower now)
                average, speed = start / closes, max(scene.ego.vx, 0.0)
                v = max(v, average if speed >= average else 2.0 * average - speed)
            if end > 0.0 and opens > 0.0:
                v = min(v, end / opens)  # not past the end before the window opens
        return float(min(max(v, 0.0), 100.0))
