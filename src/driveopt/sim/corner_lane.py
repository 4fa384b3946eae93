"""A lane that turns smoothly from one lane into another across a corner, so that a frame through the corner is smooth.

Where a route leaves a roundabout's ring for its exit, or enters the ring from its entry, the two lanes meet at an
angle (upstream's roundabout-v0: 47-59 degrees) and beside each other, not end to end. A frame that switches from
one lane's coordinates to the other's at one arc length maps a point off the joint to two places metres apart, and
its reference line turns by the whole angle at once: a plan that is smooth in the frame is a corner in the world.

:class:`CornerLane` replaces a stretch around such a joint. Its reference line is the cubic Bezier curve
from a point of the first lane to a point of the second, leaving and arriving along their directions (its inner
control points ``arms`` times the chord along each: a third each by default; a longer arm at one end moves the
turn away from it); its lateral axis turns from the first lane's to the second's with a quintic smoothstep. Its map
therefore equals each lane's map at its ends for every lateral offset (highway-env's lanes are affine in the lateral
offset), the reference line's position and heading are continuous there, and the turn is spread over the stretch,
where the planner's curvature bound sees it. Before its start it is the first lane's map, past its end the second's.

It offers what the road frame asks of a highway-env lane: ``position``, ``local_coordinates`` (the nearest of the
curve's samples, refined by Newton's method), ``heading_at`` and ``length``. Its ``longitudinal`` is the fraction
of the curve's arc length times ``length`` (the curve's parameter, tabulated against its arc length): a constant
ratio to the arc length, so that the curvature the frame reads per unit of ``longitudinal`` is the curve's own, to
that ratio (the curve's parameter alone runs unevenly along a curve with unequal arms).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

_STEP = 1e-3  # [m] finite-difference step of the lanes' directions and of Newton's Jacobian
_TOL = 1e-7  # [m] Newton's method stops when the mapped point is this close
_MAX_NEWTON = 12  # [-] iterations at most
_SAMPLES = np.linspace(0.0, 1.0, 41)  # [-] fractions of the length: the first guesses
_ARC_SAMPLES = np.linspace(0.0, 1.0, 801)  # [-] curve parameters at which the arc length is tabulated


def smoothstep(u: np.ndarray | float) -> np.ndarray | float:
    """The quintic 6u^5 - 15u^4 + 10u^3 of ``u`` clipped to [0, 1]: 0 -> 0, 1 -> 1, first and second derivatives 0
    at both ends."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * u * (u * (6.0 * u - 15.0) + 10.0)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


class CornerLane:
    """From lane ``a`` at ``a_from`` [m] along it to lane ``b`` at ``b_from + length`` [m] along it: longitudinal
    ``l`` < 0 here is ``a_from + l`` along ``a``, ``l`` > ``length`` is ``b_from + l`` along ``b``; lateral ``y`` here
    is ``y + a_lateral`` on ``a`` and ``y + b_lateral`` on ``b`` [m]; ``arms`` [-]: the Bezier curve's inner control
    points, as fractions of the chord along ``a``'s direction at the start and ``b``'s at the end."""

    def __init__(self, a: Any, a_from: float, a_lateral: float, b: Any, b_from: float, b_lateral: float,
                 length: float, arms: tuple[float, float] = (1.0 / 3.0, 1.0 / 3.0)) -> None:
        if not length > 0.0:
            raise ValueError(f"a corner lane needs a positive length, got {length!r}")
        self.a, self.a_from, self.a_lateral = a, float(a_from), float(a_lateral)
        self.b, self.b_from, self.b_lateral = b, float(b_from), float(b_lateral)
        self.length = float(length)
        start, start_across, start_along = self._frame_of(a, self.a_from, self.a_lateral)
        end, end_across, end_along = self._frame_of(b, self.b_from + self.length, self.b_lateral)
        chord = float(np.linalg.norm(end - start))
        self._controls = np.stack([start, start + arms[0] * chord * start_along, end - arms[1] * chord * end_along, end])
        self._across = np.stack([start_across, end_across])
        points = self._bezier(_ARC_SAMPLES)
        arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
        self._arc_fraction = arc / arc[-1]

    @staticmethod
    def _frame_of(lane: Any, longitudinal: float, lateral: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(point, lateral axis, unit direction) of ``lane``'s map at (``longitudinal``, ``lateral``)."""
        point = np.asarray(lane.position(longitudinal, lateral), dtype=float)
        across = np.asarray(lane.position(longitudinal, lateral + 1.0), dtype=float) - point
        ahead = np.asarray(lane.position(longitudinal + _STEP, lateral), dtype=float)
        behind = np.asarray(lane.position(longitudinal - _STEP, lateral), dtype=float)
        return point, across, _unit(ahead - behind)

    def _bezier(self, u: np.ndarray) -> np.ndarray:
        """The curve's points at parameters ``u`` in [0, 1], (len(u), 2)."""
        u = np.asarray(u, dtype=float)[:, None]
        p0, p1, p2, p3 = self._controls
        v = 1.0 - u
        return v ** 3 * p0 + 3 * v * v * u * p1 + 3 * v * u * u * p2 + u ** 3 * p3

    def _curve(self, fraction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(reference points, unit lateral axes) at ``fraction`` in [0, 1] of the curve's arc length, each
        (len(fraction), 2)."""
        fraction = np.asarray(fraction, dtype=float)
        u = np.interp(fraction, self._arc_fraction, _ARC_SAMPLES)
        w = smoothstep(fraction)[:, None]
        return self._bezier(u), _unit((1.0 - w) * self._across[0] + w * self._across[1])

    def position(self, longitudinal: float, lateral: float) -> np.ndarray:
        """[m] world position of (``longitudinal``, ``lateral``) [m]."""
        if longitudinal < 0.0:
            return np.asarray(self.a.position(self.a_from + longitudinal, lateral + self.a_lateral), dtype=float)
        if longitudinal > self.length:
            return np.asarray(self.b.position(self.b_from + longitudinal, lateral + self.b_lateral), dtype=float)
        points, across = self._curve(np.array([longitudinal / self.length]))
        return points[0] + lateral * across[0]

    def heading_at(self, longitudinal: float) -> float:
        """[rad] heading of the reference line (lateral 0) at ``longitudinal`` [m]."""
        ahead = self.position(longitudinal + _STEP, 0.0)
        behind = self.position(longitudinal - _STEP, 0.0)
        return math.atan2(ahead[1] - behind[1], ahead[0] - behind[0])

    def local_coordinates(self, position: np.ndarray) -> tuple[float, float]:
        """(longitudinal, lateral) [m] of a world ``position`` [m]: the curve's nearest sample, refined by Newton's
        method on the map."""
        position = np.asarray(position, dtype=float)
        points, across = self._curve(_SAMPLES)
        k = int(np.argmin(np.sum((points - position) ** 2, axis=1)))
        x = np.array([_SAMPLES[k] * self.length, float(np.dot(position - points[k], across[k]))])
        for _ in range(_MAX_NEWTON):
            residual = self.position(x[0], x[1]) - position
            if float(np.hypot(*residual)) < _TOL:
                break
            jacobian = np.column_stack([
                (self.position(x[0] + _STEP, x[1]) - self.position(x[0] - _STEP, x[1])) / (2 * _STEP),
                (self.position(x[0], x[1] + _STEP) - self.position(x[0], x[1] - _STEP)) / (2 * _STEP)])
            if abs(float(np.linalg.det(jacobian))) < 1e-9:
                break
            x = x - np.linalg.solve(jacobian, residual)
        return float(x[0]), float(x[1])
