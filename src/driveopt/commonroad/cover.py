"""Collision ellipses that hug a box: several axis-aligned ellipses along the box's length instead of one around it.

driveopt's collision ellipse around the Minkowski sum of two boxes (half-extents ``A`` along the road, ``B`` across
it) passes through its corners with semi-axes ``sqrt(2) * (A, B)`` (:func:`driveopt.prediction.ellipse_semi_axes`):
41 % wider than the box. Here the box is cut into ``pieces`` equal segments along its length, and each segment (half
length ``h = A / pieces``) gets the ellipse through its corners with lateral semi-axis ``stretch * B``: its
longitudinal semi-axis is then ``h / sqrt(1 - 1 / stretch^2)``. Each ellipse contains its segment, so their union
contains the box, ``stretch - 1`` of its half-width wider instead of ``sqrt(2) - 1``. :func:`cover_pieces` picks the
fewest segments whose ellipses reach no farther along the road than the single ellipse does.

The planner adds the ego's turned-box growth (``PlanningProblem.ellipse_growth``: sqrt(2) times how much the box
around the turned ego exceeds its box along the road) to every ellipse's semi-axes, segments too. That covers the
grown box at the joints of the segments (the growth there is at most the single ellipse's ratio), and at the box's
ends while the growth along the road stays small against the growth across, as it does for a car turned by a few
tenths of a radian (``tests/commonroad/test_cover.py`` checks cars and ZAM_Over's obstacle up to 0.5 rad; not a
proof for every box and heading).
"""

from __future__ import annotations

import math

import numpy as np

STRETCH = 1.2  # [-] lateral semi-axis of each segment's ellipse over the box's half-width (the single ellipse: sqrt 2)


def _check(half_long: float, half_lat: float, stretch: float) -> None:
    for name, value in (("half_long", half_long), ("half_lat", half_lat)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
            raise ValueError(f"cover {name} must be a finite number > 0 [m], got {value!r}")
    if not (isinstance(stretch, (int, float)) and 1.0 < stretch < math.sqrt(2.0)):
        raise ValueError(f"cover stretch must be in (1, sqrt 2), got {stretch!r}")


def cover_pieces(stretch: float = STRETCH) -> int:
    """[-] the fewest segments whose ellipses (:func:`box_cover`) reach no farther along the box than the single
    ellipse's ``sqrt(2) * A``: the end segment's ellipse, centred ``A - h`` from the box's centre, reaches
    ``A - h + h / q`` (``h = A / pieces``, ``q = sqrt(1 - 1 / stretch^2)``), at most ``sqrt(2) * A`` from
    ``pieces >= (1 / q - 1) / (sqrt(2) - 1)`` on (2 at the default stretch)."""
    _check(1.0, 1.0, stretch)
    q = math.sqrt(1.0 - 1.0 / stretch**2)
    return max(1, math.ceil((1.0 / q - 1.0) / (math.sqrt(2.0) - 1.0) - 1e-9))


def box_cover(half_long: float, half_lat: float, stretch: float = STRETCH,
              pieces: int | None = None) -> tuple[np.ndarray, float, float]:
    """(centres (pieces,) [m] along the box from its centre, longitudinal semi-axis [m], lateral semi-axis [m]) of the
    ellipses covering a box of half-extents ``half_long`` x ``half_lat`` [m], one per equal segment of its length
    (``pieces``: :func:`cover_pieces` by default), each through its segment's corners with lateral semi-axis
    ``stretch * half_lat``. ValueError for a non-positive extent, a stretch outside (1, sqrt 2) or pieces < 1."""
    _check(half_long, half_lat, stretch)
    pieces = cover_pieces(stretch) if pieces is None else pieces
    if isinstance(pieces, bool) or not isinstance(pieces, int) or pieces < 1:
        raise ValueError(f"cover pieces must be an integer >= 1, got {pieces!r}")
    h = half_long / pieces  # [m] half-length of a segment
    centres = -half_long + h * (2.0 * np.arange(pieces) + 1.0)
    return centres, h / math.sqrt(1.0 - 1.0 / stretch**2), stretch * half_lat
