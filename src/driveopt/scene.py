"""The world one planning call sees: ego, road, neighbours, desired speed; problem files in and out.

Coordinates are the road (Frenet) frame: ``x`` along the road centre line, ``y``
across it, both in metres, ``y`` growing to the left of travel in the road frame
(highway-env's ``y`` grows downwards on screen; the frame is the same).

A :class:`Scene` is validated on construction; :func:`driveopt.problem.build_problem` turns it
into the arrays the planner consumes. Problem files are JSON (:func:`scene_from_dict`,
:func:`scene_to_dict`, :func:`load_scene`); the built-in ones ship in ``driveopt/problems/``.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from driveopt.errors import DriveoptError, UnknownNameError
from driveopt.jsonfile import is_valid_unicode, read_json


class ProblemError(DriveoptError):
    """The planning problem is malformed (wrong shape, non-finite, inconsistent)."""


# The physical range of every number of a scene: (lowest, highest, unit). Beyond it a problem is refused
# rather than planned in float32 (where, e.g., a speed of 1e30 m/s has no finite trajectory).
RANGES = {
    "x": (-1e5, 1e5, "m"), "y": (-1e3, 1e3, "m"),
    "vx": (-100.0, 100.0, "m/s"), "vy": (-100.0, 100.0, "m/s"),
    "ax": (-100.0, 100.0, "m/s^2"), "ay": (-100.0, 100.0, "m/s^2"), "accel": (-100.0, 100.0, "m/s^2"),
    "length": (0.1, 100.0, "m"), "width": (0.1, 100.0, "m"), "yaw": (-100.0, 100.0, "rad"),
    "lane_width": (0.5, 100.0, "m"), "first_lane_center": (-1e3, 1e3, "m"), "curvature": (-1.0, 1.0, "1/m"),
    "curvature_origin": (-1e3, 1e3, "m"), "lane_center": (-1e3, 1e3, "m"),
    "longitudinal": (0.0, 100.0, "m"), "lateral": (0.0, 100.0, "m"),
    "v_des": (0.0, 100.0, "m/s"), "slowing": (0.0, 20.0, "m/s^2"), "slowing_from": (0.0, 100.0, "m/s"),
    "edge_margin": (0.0, 100.0, "m"), "time_gap": (0.0, 10.0, "s"),
}
MAX_LANES = 64  # [-] lanes of a road
CURVATURE_CELL = 2.5  # [m] length of a cell of Road.curvature_ahead
CURVATURE_CELLS = 80  # [-] cells of Road.curvature_ahead: 200 m, what 40 m/s covers in a 5 s horizon
# [-] the least (1 - k (y - y0)) taken for a car at y [m] beside a line at y0 of curvature k [1/m], whose speed is that
# factor times its rate along the line: near a curve's centre the true factor would free a plan's rate without bound,
# so the bound on the car's speed is kept from below there (conservative)
PATH_SCALE_MIN = 0.5


def _number(name: str, value: Any, field: str | None = None) -> float:
    """``value`` as a float after checking that it is a real number (not a bool or a string), finite,
    and within ``RANGES[field]`` (field: the last part of ``name`` by default)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ProblemError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ProblemError(f"{name} must be finite, got {v}")
    low, high, unit = RANGES[field or name.rpartition(".")[2]]
    if not low <= v <= high:
        raise ProblemError(f"{name} must be within [{low:g}, {high:g}] {unit}, got {v:g}")
    return v


BOX_MIN_SPEED = 0.5  # [m/s] below this speed a car without a given yaw is taken to point along the road


CAR_LENGTH, CAR_WIDTH = 5.0, 2.0  # [m] highway-env's default vehicle


@dataclass(frozen=True)
class EgoState:
    """Ego vehicle state in the road frame."""

    x: float  # [m]
    y: float  # [m]
    vx: float  # [m/s]
    vy: float = 0.0  # [m/s]
    ax: float = 0.0  # [m/s^2]
    ay: float = 0.0  # [m/s^2]
    length: float = CAR_LENGTH  # [m]
    width: float = CAR_WIDTH  # [m]
    yaw: float | None = None  # [rad] body heading relative to the road; None: the velocity's direction

    def __post_init__(self) -> None:
        for f in ("x", "y", "vx", "vy", "ax", "ay", "length", "width"):
            object.__setattr__(self, f, _number(f"ego.{f}", getattr(self, f)))
        if self.yaw is not None:
            object.__setattr__(self, "yaw", _number("ego.yaw", self.yaw))

    @property
    def speed(self) -> float:
        return math.hypot(self.vx, self.vy)

    @property
    def heading(self) -> float:
        """[rad] direction of travel relative to the road."""
        return math.atan2(self.vy, self.vx) if self.speed > 1e-6 else 0.0

    @property
    def box_heading(self) -> float:
        """[rad] heading of the ego's box: ``yaw`` when given, else the direction of travel above
        :data:`BOX_MIN_SPEED` (0 when nearly stopped)."""
        if self.yaw is not None:
            return self.yaw
        return self.heading if self.speed > BOX_MIN_SPEED else 0.0


@dataclass(frozen=True)
class Neighbour:
    """Another vehicle, observed now; predicted by :func:`driveopt.prediction.predict_neighbour`."""

    x: float  # [m]
    y: float  # [m]
    vx: float = 0.0  # [m/s]
    vy: float = 0.0  # [m/s]
    length: float = CAR_LENGTH  # [m]
    width: float = CAR_WIDTH  # [m]
    yaw: float | None = None  # [rad] body heading relative to the road; None: the velocity's direction
    accel: float = 0.0  # [m/s^2] acceleration along the velocity (< 0: braking); only braking is extrapolated
    lane_center: float | None = None  # [m] y of the centre of the lane it steers to (a simulated car's target lane):
    # its predicted lateral motion ends there; None: at its lateral rate throughout (P1)

    def __post_init__(self) -> None:
        for f in ("x", "y", "vx", "vy", "length", "width", "accel"):
            object.__setattr__(self, f, _number(f"neighbour.{f}", getattr(self, f)))
        for f in ("yaw", "lane_center"):
            if getattr(self, f) is not None:
                object.__setattr__(self, f, _number(f"neighbour.{f}", getattr(self, f)))

    @property
    def heading(self) -> float:
        """[rad] heading of the box: ``yaw`` when given, else from the velocity (0 when nearly stopped)."""
        if self.yaw is not None:
            return self.yaw
        return math.atan2(self.vy, self.vx) if math.hypot(self.vx, self.vy) > BOX_MIN_SPEED else 0.0

    @property
    def half_extents(self) -> tuple[float, float]:
        """[m] half-length and half-width of the axis-aligned box around the (rotated) vehicle."""
        c, s = abs(math.cos(self.heading)), abs(math.sin(self.heading))
        return 0.5 * (self.length * c + self.width * s), 0.5 * (self.length * s + self.width * c)


@dataclass(frozen=True)
class Road:
    """Straight (or constant-curvature) multi-lane road; lane i is centred at first_lane_center + i * lane_width."""

    num_lanes: int = 4  # [-]
    lane_width: float = 4.0  # [m]
    first_lane_center: float = 0.0  # [m]
    curvature: float = 0.0  # [1/m] signed curvature of the centre line at the ego
    # [1/m] the signed curvature of largest magnitude of the centre line in each of CURVATURE_CELLS cells of
    # CURVATURE_CELL metres ahead of the ego (the first reaching back over the ego's length; positive: turning towards
    # +y): the centripetal bound at a plan's node reads the cell the node is in. Empty: ``curvature`` everywhere (a
    # constant-curvature road).
    curvature_ahead: tuple[float, ...] = ()
    # [m] y of the line whose curvature ``curvature`` and ``curvature_ahead`` give, along which speeds in x are rates: a
    # car at y moves (1 - k (y - curvature_origin)) times as fast as its rate, on a path of curvature k / (that factor)
    curvature_origin: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.num_lanes, int) or isinstance(self.num_lanes, bool) or not 1 <= self.num_lanes <= MAX_LANES:
            raise ProblemError(f"road.num_lanes must be an int in [1, {MAX_LANES}], got {self.num_lanes!r}")
        for f in ("lane_width", "first_lane_center", "curvature", "curvature_origin"):
            object.__setattr__(self, f, _number(f"road.{f}", getattr(self, f)))
        cells = self.curvature_ahead
        if isinstance(cells, (str, bytes)) or not isinstance(cells, (tuple, list, np.ndarray)) or len(cells) not in (0, CURVATURE_CELLS):
            raise ProblemError(f"road.curvature_ahead must be empty or a list of {CURVATURE_CELLS} curvatures [1/m], "
                               f"got {cells!r:.80}")
        values = tuple(_number(f"road.curvature_ahead[{i}]", c, "curvature") for i, c in enumerate(cells))
        object.__setattr__(self, "curvature_ahead", values)

    @property
    def curvature_profile(self) -> np.ndarray:
        """[1/m] (CURVATURE_CELLS,) :attr:`curvature_ahead`, or ``curvature`` in every cell where it is empty (signed)."""
        if self.curvature_ahead:
            return np.asarray(self.curvature_ahead, dtype=float)
        return np.full(CURVATURE_CELLS, self.curvature)

    @property
    def lane_centers(self) -> np.ndarray:
        return self.first_lane_center + self.lane_width * np.arange(self.num_lanes)

    @property
    def edges(self) -> tuple[float, float]:
        """[m] (lower, upper) road edges."""
        lo = self.first_lane_center - 0.5 * self.lane_width
        return lo, lo + self.num_lanes * self.lane_width


@dataclass(frozen=True)
class EllipseMargin:
    """Extra clearance added to each semi-axis of the collision ellipse.

    ``time_gap`` [s]: the longitudinal semi-axis of a car following its lane (a :class:`Neighbour`, not crossing
    traffic) grows by this time at the ego's forward speed, so a plan keeps a headway to the car it follows and does
    not cut in just ahead of or behind a car in the lane it enters, whose braking or speed the constant-speed
    prediction does not foresee (0: the ellipse of the two boxes alone)."""

    longitudinal: float = 0.5  # [m]
    lateral: float = 0.3  # [m]
    time_gap: float = 0.0  # [s]

    def __post_init__(self) -> None:
        for f in ("longitudinal", "lateral", "time_gap"):
            object.__setattr__(self, f, _number(f"ellipse_margin.{f}", getattr(self, f)))


@dataclass(frozen=True)
class Scene:
    """Everything one planning call needs to know about the world."""

    ego: EgoState
    road: Road = field(default_factory=Road)
    neighbours: tuple[Neighbour, ...] = ()
    v_des: float = 20.0  # [m/s] desired speed
    slowing: float = 0.0  # [m/s^2] the rate at which the speed asked for comes down from slowing_from to v_des
    slowing_from: float = 0.0  # [m/s] the most asked for now: above v_des where a car faster than v_des is let slow to
    # it at the rate slowing rather than at once, from its speed (driveopt.costs.speed_reference); at or below v_des:
    # v_des throughout
    ellipse_margin: EllipseMargin = field(default_factory=EllipseMargin)
    edge_margin: float = 0.0  # [m] extra distance the ego's side keeps from the road edge
    name: str = "custom"

    def __post_init__(self) -> None:
        object.__setattr__(self, "neighbours", tuple(self.neighbours))
        object.__setattr__(self, "v_des", _number("v_des", self.v_des))
        object.__setattr__(self, "slowing", _number("slowing", self.slowing))
        object.__setattr__(self, "slowing_from", _number("slowing_from", self.slowing_from))
        object.__setattr__(self, "edge_margin", _number("edge_margin", self.edge_margin))
        if not isinstance(self.name, str):
            raise ProblemError(f"name must be a string, got {self.name!r}")
        if not is_valid_unicode(self.name):
            raise ProblemError(f"name {self.name!r} is not valid Unicode (a lone surrogate)")
        lo, hi = self.lateral_bounds
        if lo >= hi:
            raise ProblemError("the road is narrower than the ego vehicle plus edge margins")

    @property
    def lateral_bounds(self) -> tuple[float, float]:
        """[m] bounds on the ego centre's y that keep its box on the road."""
        lo, hi = self.road.edges
        half = 0.5 * self.ego.width + self.edge_margin
        return lo + half, hi - half


def scene_to_dict(scene: Scene) -> dict[str, Any]:
    """JSON-ready dict of a scene (the documented problem-file format)."""
    return {
        "name": scene.name,
        "v_des": scene.v_des,
        **{name: getattr(scene, name) for name in ("slowing", "slowing_from") if getattr(scene, name)},
        "road": {k: v for k, v in asdict(scene.road).items() if k not in ("curvature_ahead", "curvature_origin") or v},
        "ego": asdict(scene.ego),
        "neighbours": [asdict(n) for n in scene.neighbours],
        "ellipse_margin": asdict(scene.ellipse_margin),
        "edge_margin": scene.edge_margin,
    }


_TOP_KEYS = {"name", "description", "v_des", "slowing", "slowing_from", "road", "ego", "neighbours", "ellipse_margin",
             "edge_margin"}


def _build(cls: type, values: dict[str, Any], where: str) -> Any:
    """``cls(**values)`` after checking the keys: a misspelt or missing key is a ProblemError naming ``where``
    and listing the valid keys (a TypeError from the constructor would name neither)."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise ProblemError(f"unknown key(s) {unknown} in '{where}'; valid: {sorted(fields)}")
    missing = sorted(name for name, f in fields.items() if name not in values and f.default is dataclasses.MISSING
                     and f.default_factory is dataclasses.MISSING)
    if missing:
        raise ProblemError(f"'{where}' is missing {missing}")
    return cls(**values)


def _section(data: dict[str, Any], key: str, cls: type, required: bool) -> Any:
    if key not in data:
        if required:
            raise ProblemError(f"problem file is missing '{key}'")
        return cls()
    value = data[key]
    if not isinstance(value, dict):
        raise ProblemError(f"'{key}' must be an object")
    return _build(cls, value, key)


def scene_from_dict(data: Any) -> Scene:
    """Parse the problem-file format; every defect raises ProblemError with the offending key."""
    if not isinstance(data, dict):
        raise ProblemError("problem file must hold a JSON object")
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise ProblemError(f"unknown key(s) in problem file: {unknown}; valid: {sorted(_TOP_KEYS)}")
    neighbours = data.get("neighbours", [])
    if not isinstance(neighbours, list):
        raise ProblemError("'neighbours' must be a list")
    parsed = []
    for i, n in enumerate(neighbours):
        if not isinstance(n, dict):
            raise ProblemError(f"neighbours[{i}] must be an object")
        try:
            parsed.append(_build(Neighbour, n, f"neighbours[{i}]"))
        except ProblemError as exc:
            message = str(exc)
            raise ProblemError(message if f"neighbours[{i}]" in message else f"neighbours[{i}]: {message}") from None
    return Scene(
        ego=_section(data, "ego", EgoState, required=True),
        road=_section(data, "road", Road, required=False),
        neighbours=tuple(parsed),
        v_des=data.get("v_des", 20.0),
        slowing=data.get("slowing", 0.0),
        slowing_from=data.get("slowing_from", 0.0),
        ellipse_margin=_section(data, "ellipse_margin", EllipseMargin, required=False),
        edge_margin=data.get("edge_margin", 0.0),
        name=data.get("name", "custom"),
    )


BUILTIN_DIR = Path(__file__).parent / "problems"


class UnknownProblemError(ProblemError, UnknownNameError):
    """No built-in problem of that name and no such file."""


def builtin_problems() -> list[str]:
    """Names of the problems shipped with the package."""
    return sorted(p.stem for p in BUILTIN_DIR.glob("*.json"))


def load_scene(name_or_path: str | Path) -> Scene:
    """Load a built-in problem by name, or a problem file by path (read by :func:`driveopt.jsonfile.read_json`,
    which refuses special files, huge files, deep nesting, huge numbers and invalid Unicode)."""
    path = Path(name_or_path)
    if _is_bare_name(name_or_path):
        if (BUILTIN_DIR / f"{name_or_path}.json").exists():
            path = BUILTIN_DIR / f"{name_or_path}.json"
        elif not path.exists():
            raise UnknownProblemError(f"no problem named '{name_or_path}'; built-in problems: {builtin_problems()}, "
                                      "or give a JSON file path")
    return scene_from_dict(read_json(path, "problem file", ProblemError))


def _is_bare_name(name_or_path: str | Path) -> bool:
    """Whether ``name_or_path`` reads as a problem's name (no suffix, no folder) rather than a file path."""
    text = str(name_or_path)
    return not Path(text).suffix and "/" not in text and os.sep not in text
