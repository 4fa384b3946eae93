"""Planning problems: the user-facing scene and the array form the planner consumes.

Coordinates are the road (Frenet) frame: ``x`` along the road centre line, ``y``
across it, both in metres, ``y`` growing to the left of travel in the road frame
(highway-env's ``y`` grows downwards on screen; the frame is the same).

A :class:`Scene` (ego, road, neighbours, desired speed) is validated on
construction and turned into a :class:`PlanningProblem` pytree by
:func:`build_problem`: neighbours are predicted with constant velocity (braking
ones keep braking for a while, :func:`predict_neighbour`), the nearest
``max_obstacles`` are kept (masked padding when fewer), and each gets a
collision ellipse that circumscribes the Minkowski sum of the two vehicle boxes.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from driveopt.config import BasisConfig


class ProblemError(ValueError):
    """The planning problem is malformed (wrong shape, non-finite, inconsistent)."""


def _finite(name: str, value: Any) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ProblemError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ProblemError(f"{name} must be finite, got {v}")
    return v


@dataclass(frozen=True)
class EgoState:
    """Ego vehicle state in the road frame."""

    x: float  # [m]
    y: float  # [m]
    vx: float  # [m/s]
    vy: float = 0.0  # [m/s]
    ax: float = 0.0  # [m/s^2]
    ay: float = 0.0  # [m/s^2]
    length: float = 5.0  # [m] (highway-env default vehicle)
    width: float = 2.0  # [m]

    def __post_init__(self) -> None:
        for f in ("x", "y", "vx", "vy", "ax", "ay", "length", "width"):
            object.__setattr__(self, f, _finite(f"ego.{f}", getattr(self, f)))
        if self.length <= 0 or self.width <= 0:
            raise ProblemError("ego.length and ego.width must be > 0 [m]")

    @property
    def speed(self) -> float:
        return math.hypot(self.vx, self.vy)

    @property
    def heading(self) -> float:
        """[rad] direction of travel relative to the road."""
        return math.atan2(self.vy, self.vx) if self.speed > 1e-6 else 0.0


@dataclass(frozen=True)
class Neighbour:
    """Another vehicle, observed now; predicted with constant velocity, or braking (:func:`predict_neighbour`)."""

    x: float  # [m]
    y: float  # [m]
    vx: float = 0.0  # [m/s]
    vy: float = 0.0  # [m/s]
    length: float = 5.0  # [m]
    width: float = 2.0  # [m]
    yaw: float | None = None  # [rad] body heading relative to the road; None: the velocity's direction
    accel: float = 0.0  # [m/s^2] acceleration along the velocity (< 0: braking); only braking is extrapolated

    def __post_init__(self) -> None:
        for f in ("x", "y", "vx", "vy", "length", "width", "accel"):
            object.__setattr__(self, f, _finite(f"neighbour.{f}", getattr(self, f)))
        if self.yaw is not None:
            object.__setattr__(self, "yaw", _finite("neighbour.yaw", self.yaw))
        if self.length <= 0 or self.width <= 0:
            raise ProblemError("neighbour.length and neighbour.width must be > 0 [m]")

    @property
    def heading(self) -> float:
        """[rad] heading of the box: ``yaw`` when given, else from the velocity (0 when nearly stopped)."""
        if self.yaw is not None:
            return self.yaw
        return math.atan2(self.vy, self.vx) if math.hypot(self.vx, self.vy) > 0.5 else 0.0

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
    curvature: float = 0.0  # [1/m] signed curvature of the centre line (used by the centripetal bound)

    def __post_init__(self) -> None:
        if not isinstance(self.num_lanes, int) or isinstance(self.num_lanes, bool) or self.num_lanes < 1:
            raise ProblemError(f"road.num_lanes must be an int >= 1, got {self.num_lanes!r}")
        for f in ("lane_width", "first_lane_center", "curvature"):
            object.__setattr__(self, f, _finite(f"road.{f}", getattr(self, f)))
        if self.lane_width <= 0:
            raise ProblemError("road.lane_width must be > 0 [m]")

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
    """Extra clearance added to each semi-axis of the collision ellipse."""

    longitudinal: float = 0.5  # [m]
    lateral: float = 0.3  # [m] also covers the ego box turning by up to ~0.1 rad

    def __post_init__(self) -> None:
        for f in ("longitudinal", "lateral"):
            v = _finite(f"ellipse_margin.{f}", getattr(self, f))
            if v < 0:
                raise ProblemError(f"ellipse_margin.{f} must be >= 0 [m]")
            object.__setattr__(self, f, v)


@dataclass(frozen=True)
class Scene:
    """Everything one planning call needs to know about the world."""

    ego: EgoState
    road: Road = field(default_factory=Road)
    neighbours: tuple[Neighbour, ...] = ()
    v_des: float = 20.0  # [m/s] desired speed
    ellipse_margin: EllipseMargin = field(default_factory=EllipseMargin)
    edge_margin: float = 0.0  # [m] extra distance the ego's side keeps from the road edge
    name: str = "custom"

    def __post_init__(self) -> None:
        object.__setattr__(self, "neighbours", tuple(self.neighbours))
        object.__setattr__(self, "v_des", _finite("v_des", self.v_des))
        object.__setattr__(self, "edge_margin", _finite("edge_margin", self.edge_margin))
        if self.v_des < 0:
            raise ProblemError("v_des must be >= 0 [m/s]")
        lo, hi = self.lateral_bounds
        if lo >= hi:
            raise ProblemError("the road is narrower than the ego vehicle plus edge margins")

    @property
    def lateral_bounds(self) -> tuple[float, float]:
        """[m] bounds on the ego centre's y that keep its box on the road."""
        lo, hi = self.road.edges
        half = 0.5 * self.ego.width + self.edge_margin
        return lo + half, hi - half


class PlanningProblem(NamedTuple):
    """Array form of a scene in the planning frame (ego at x = 0). A JAX pytree.

    Shapes: N obstacles, K time nodes.
    """

    init_x: jnp.ndarray  # (3,) [m, m/s, m/s^2] x, x', x'' at t = 0
    init_y: jnp.ndarray  # (3,) [m, m/s, m/s^2] y, y', y'' at t = 0
    y_lb: jnp.ndarray  # () [m] lower bound of the ego centre
    y_ub: jnp.ndarray  # () [m] upper bound of the ego centre
    lane_center0: jnp.ndarray  # () [m] centre of the lowest lane
    lane_width: jnp.ndarray  # () [m]
    num_lanes: jnp.ndarray  # () [-] as float
    road_curvature: jnp.ndarray  # () [1/m]
    v_des: jnp.ndarray  # () [m/s]
    obstacle_x: jnp.ndarray  # (N, K) [m] predicted centres
    obstacle_y: jnp.ndarray  # (N, K) [m]
    obstacle_a: jnp.ndarray  # (N,) [m] longitudinal semi-axis of the collision ellipse
    obstacle_b: jnp.ndarray  # (N,) [m] lateral semi-axis
    obstacle_mask: jnp.ndarray  # (N,) 1.0 for a real obstacle, 0.0 for padding
    observation: jnp.ndarray  # (55,) the learned priors' input (driveopt.observation)


def ellipse_semi_axes(ego: EgoState, other: Neighbour, margin: EllipseMargin) -> tuple[float, float]:
    """[m] semi-axes of the ellipse that circumscribes the Minkowski sum of the two boxes, plus margins.

    The axis-aligned ellipse with semi-axes sqrt(2) * (A, B) passes through the corners of a
    box with half-sides (A, B): outside it, the two axis-aligned boxes cannot overlap. The
    neighbour's box is first replaced by the axis-aligned box around it at its heading, so a car
    turned across the road (changing lanes steeply, or stopped askew after a crash) is covered.
    """
    other_long, other_lat = other.half_extents
    half_long = 0.5 * ego.length + other_long
    half_lat = 0.5 * ego.width + other_lat
    return math.sqrt(2.0) * half_long + margin.longitudinal, math.sqrt(2.0) * half_lat + margin.lateral


BRAKING_TIME = 3.0  # [s] how long an observed braking is assumed to last in predictions


def predict_neighbour(
    n: Neighbour, t: np.ndarray, y_range: tuple[float, float], braking_time: float = BRAKING_TIME
) -> tuple[np.ndarray, np.ndarray]:
    """[m] predicted centre of a neighbour at times t [s]; y kept on the road.

    Constant velocity, except that a braking neighbour (``accel`` < 0) keeps braking for
    ``braking_time`` s (never reversing), then holds its speed: a car braking hard for a jam ahead
    of it would otherwise be predicted to keep going and the ego would react a second late.
    Acceleration is not extrapolated (a constant-velocity leader is the safer assumption).
    """
    speed = math.hypot(n.vx, n.vy)
    decel = -min(n.accel, 0.0)
    if decel == 0.0 or speed < 1e-6:
        return n.x + n.vx * t, np.clip(n.y + n.vy * t, *y_range)
    braking = min(braking_time, speed / decel)
    tau = np.minimum(t, braking)
    distance = speed * tau - 0.5 * decel * tau**2 + (speed - decel * braking) * (t - tau)
    return n.x + n.vx / speed * distance, np.clip(n.y + n.vy / speed * distance, *y_range)


def is_follower(scene: Scene, n: Neighbour) -> bool:
    """A neighbour behind the ego in the ego's lane (it is the one that must keep its distance)."""
    return n.x < scene.ego.x and abs(n.y - scene.ego.y) < 0.5 * scene.road.lane_width


def nearest_neighbours(scene: Scene, count: int, ignore_followers: bool = False) -> list[Neighbour]:
    """The ``count`` neighbours closest to the ego (Euclidean distance now), nearest first."""
    ego = scene.ego
    candidates = [n for n in scene.neighbours if not (ignore_followers and is_follower(scene, n))]
    return sorted(candidates, key=lambda n: math.hypot(n.x - ego.x, n.y - ego.y))[:count]


def build_problem(
    scene: Scene, basis: BasisConfig = BasisConfig(), max_obstacles: int = 10, ignore_followers: bool = False
) -> PlanningProblem:
    """Turn a scene into the planner's arrays, in the frame where the ego starts at x = 0.

    ignore_followers: leave out same-lane vehicles behind the ego. Constant-velocity prediction
    drives a faster follower straight through a slow ego, which no plan can avoid, whereas
    car-following traffic (IDM) brakes for the vehicle ahead of it.
    """
    if not isinstance(scene, Scene):
        raise ProblemError(f"build_problem needs a Scene, got {type(scene).__name__}")
    if max_obstacles < 1:
        raise ProblemError("max_obstacles must be >= 1")
    from driveopt.observation import observation_vector  # imports this module

    t = np.linspace(0.0, basis.horizon, basis.num_nodes)
    ego = scene.ego
    y_lb, y_ub = scene.lateral_bounds
    K, N = basis.num_nodes, max_obstacles
    # Padding: far behind the ego, masked out; values stay moderate for float32.
    ox = np.full((N, K), -1000.0)
    oy = np.full((N, K), 0.5 * (y_lb + y_ub))
    oa = np.ones(N)
    ob = np.ones(N)
    mask = np.zeros(N)
    for i, n in enumerate(nearest_neighbours(scene, N, ignore_followers)):
        px, py = predict_neighbour(n, t, scene.road.edges)
        ox[i], oy[i] = px - ego.x, py
        oa[i], ob[i] = ellipse_semi_axes(ego, n, scene.ellipse_margin)
        mask[i] = 1.0
    f32 = lambda v: jnp.asarray(v, dtype=jnp.float32)  # noqa: E731
    return PlanningProblem(
        init_x=f32([0.0, ego.vx, ego.ax]),
        init_y=f32([ego.y, ego.vy, ego.ay]),
        y_lb=f32(y_lb),
        y_ub=f32(y_ub),
        lane_center0=f32(scene.road.first_lane_center),
        lane_width=f32(scene.road.lane_width),
        num_lanes=f32(scene.road.num_lanes),
        road_curvature=f32(scene.road.curvature),
        v_des=f32(scene.v_des),
        obstacle_x=f32(ox),
        obstacle_y=f32(oy),
        obstacle_a=f32(oa),
        obstacle_b=f32(ob),
        obstacle_mask=f32(mask),
        observation=f32(observation_vector(scene)),
    )


def check_problem(problem: PlanningProblem, basis: BasisConfig = BasisConfig()) -> None:
    """Raise ProblemError unless every array of ``problem`` is finite and has the right shape."""
    if not isinstance(problem, PlanningProblem):
        raise ProblemError(f"expected a PlanningProblem, got {type(problem).__name__}")
    from driveopt.observation import OBSERVATION_DIM

    K = basis.num_nodes
    N = np.shape(problem.obstacle_x)[0] if np.ndim(problem.obstacle_x) == 2 else -1
    expected = {
        "init_x": (3,), "init_y": (3,), "y_lb": (), "y_ub": (), "lane_center0": (), "lane_width": (),
        "num_lanes": (), "road_curvature": (), "v_des": (), "obstacle_x": (N, K), "obstacle_y": (N, K),
        "obstacle_a": (N,), "obstacle_b": (N,), "obstacle_mask": (N,), "observation": (OBSERVATION_DIM,),
    }
    for name, shape in expected.items():
        value = np.asarray(getattr(problem, name))
        if value.shape != shape:
            raise ProblemError(f"problem.{name} has shape {value.shape}, expected {shape} (K = {K} nodes)")
        if not np.all(np.isfinite(value)):
            raise ProblemError(f"problem.{name} contains NaN or inf")
    if N < 1:
        raise ProblemError("problem needs at least one (possibly masked) obstacle row")
    if not float(problem.y_lb) < float(problem.y_ub):
        raise ProblemError("problem.y_lb must be below problem.y_ub")
    if np.any(np.asarray(problem.obstacle_a) <= 0) or np.any(np.asarray(problem.obstacle_b) <= 0):
        raise ProblemError("obstacle ellipse semi-axes must be > 0")


# --------------------------------------------------------------------------- JSON files

def scene_to_dict(scene: Scene) -> dict[str, Any]:
    """JSON-ready dict of a scene (the documented problem-file format)."""
    return {
        "name": scene.name,
        "v_des": scene.v_des,
        "road": asdict(scene.road),
        "ego": asdict(scene.ego),
        "neighbours": [asdict(n) for n in scene.neighbours],
        "ellipse_margin": asdict(scene.ellipse_margin),
        "edge_margin": scene.edge_margin,
    }


_TOP_KEYS = {"name", "description", "v_des", "road", "ego", "neighbours", "ellipse_margin", "edge_margin"}


def _section(data: dict[str, Any], key: str, cls: type, required: bool) -> Any:
    if key not in data:
        if required:
            raise ProblemError(f"problem file is missing '{key}'")
        return cls()
    value = data[key]
    if not isinstance(value, dict):
        raise ProblemError(f"'{key}' must be an object")
    try:
        return cls(**value)
    except TypeError as exc:
        raise ProblemError(f"bad '{key}': {exc}") from None


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
            parsed.append(Neighbour(**n))
        except TypeError as exc:
            raise ProblemError(f"bad neighbours[{i}]: {exc}") from None
        except ProblemError as exc:
            raise ProblemError(f"neighbours[{i}]: {exc}") from None
    return Scene(
        ego=_section(data, "ego", EgoState, required=True),
        road=_section(data, "road", Road, required=False),
        neighbours=tuple(parsed),
        v_des=data.get("v_des", 20.0),
        ellipse_margin=_section(data, "ellipse_margin", EllipseMargin, required=False),
        edge_margin=data.get("edge_margin", 0.0),
        name=str(data.get("name", "custom")),
    )


BUILTIN_DIR = Path(__file__).parent / "problems"


def builtin_problems() -> list[str]:
    """Names of the problems shipped with the package."""
    return sorted(p.stem for p in BUILTIN_DIR.glob("*.json"))


def load_scene(name_or_path: str | Path) -> Scene:
    """Load a built-in problem by name, or a problem file by path."""
    path = Path(name_or_path)
    if not path.suffix and (BUILTIN_DIR / f"{name_or_path}.json").exists():
        path = BUILTIN_DIR / f"{name_or_path}.json"
    if not path.exists():
        raise ProblemError(f"no problem named '{name_or_path}'; built-in problems: {builtin_problems()}, or give a JSON file path")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ProblemError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ProblemError(f"{path}: cannot read ({exc})") from None
    return scene_from_dict(data)
