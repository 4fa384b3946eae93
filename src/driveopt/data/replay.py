"""The planning problem of a demonstration row, rebuilt from what the row stores (for offline evaluation).

A row keeps the 55-dim observation, the ego's initial state and its lane bounds, not the scene. The
scene is read back from them:

- road: straight, lanes ``lane_width`` wide (highway-env: 4 m); the lowest lane centre and the lane
  count follow from the ego-centre bounds, ``y_lb = c_0 - lane_width / 2 + ego_width / 2`` and
  ``y_ub - y_lb = num_lanes * lane_width - ego_width``;
- ego at x = 0 with the row's ``init_x`` / ``init_y`` (position, velocity, acceleration);
- neighbours: the observation's real rows (:func:`driveopt.observation.neighbour_mask`): position
  relative to the ego, road-frame velocity and heading; highway-env's 5 x 2 m cars.

What the row does not keep is assumed: neighbours' accelerations (0: constant-velocity prediction,
where the closed loop predicts a braking car to keep braking) and vehicles beyond the 10 nearest
(the closed loop plans against the 10 that come closest within 4 s among all of them). The problem
is built as the closed-loop driver builds it (same-lane followers left out), and its observation,
initial state and lane bounds are the row's own, exactly.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from driveopt.basis import make_basis
from driveopt.config import BasisConfig
from driveopt.data.demonstrations import DatasetError, Demonstrations
from driveopt.data.modes import lanes_per_row
from driveopt.observation import NEIGHBOUR_FEATURES, ObservationError, neighbour_mask, split_observation
from driveopt.problem import PlanningProblem, build_problem
from driveopt.scene import EgoState, Neighbour, ProblemError, Road, Scene

LANE_WIDTH = 4.0  # [m] highway-env's lanes
VEHICLE_LENGTH = 5.0  # [m] highway-env's cars
VEHICLE_WIDTH = 2.0  # [m]


def road_from_bounds(y_lb: float, y_ub: float, lane_width: float = LANE_WIDTH, ego_width: float = VEHICLE_WIDTH) -> Road:
    """The straight road whose ego-centre bounds [m] are (y_lb, y_ub); DatasetError when they fit no whole lane count."""
    lanes = (y_ub - y_lb + ego_width) / lane_width
    if not (np.isfinite(lanes) and round(lanes) >= 1 and abs(lanes - round(lanes)) < 1e-3):
        raise DatasetError(f"lane bounds ({y_lb:g}, {y_ub:g}) m fit no whole number of {lane_width:g} m lanes for a "
                           f"{ego_width:g} m wide ego")
    return Road(num_lanes=int(round(lanes)), lane_width=lane_width, first_lane_center=y_lb + 0.5 * (lane_width - ego_width))


def scene_from_observation(observation: np.ndarray, init_x: np.ndarray, init_y: np.ndarray, lane_bounds: np.ndarray,
                           v_des: float, name: str = "demonstration row") -> Scene:
    """The scene a row describes (see the module docstring): observation (55,), init_x / init_y (3,) [m, m/s, m/s^2]
    (x in the planning frame, y in the road frame), lane_bounds (2,) [m], v_des [m/s]."""
    obs = np.asarray(observation, np.float64)
    _, rows = split_observation(obs)
    ego_y = float(init_y[0])
    ego = EgoState(x=0.0, y=ego_y, vx=float(init_x[1]), vy=float(init_y[1]), ax=float(init_x[2]), ay=float(init_y[2]),
                   length=VEHICLE_LENGTH, width=VEHICLE_WIDTH)
    neighbours = tuple(
        Neighbour(x=float(dx), y=ego_y + float(dy), vx=float(vx), vy=float(vy), length=VEHICLE_LENGTH, width=VEHICLE_WIDTH,
                  yaw=float(heading))
        for (dx, dy, vx, vy, heading) in rows[np.asarray(neighbour_mask(obs))].reshape(-1, NEIGHBOUR_FEATURES)
    )
    return Scene(ego=ego, road=road_from_bounds(float(lane_bounds[0]), float(lane_bounds[1])), neighbours=neighbours,
                 v_des=float(v_des), name=name)


def problem_from_row(data: Demonstrations, row: int, v_des: float, basis: BasisConfig = BasisConfig()) -> PlanningProblem:
    """The planning problem of demonstration row ``row`` (see the module docstring); DatasetError when the row's
    values describe no valid scene."""
    try:
        scene = scene_from_observation(data.observation[row], data.init_x[row], data.init_y[row], data.lane_bounds[row], v_des,
                                       name=f"row {row}")
        problem = build_problem(scene, basis, ignore_followers=True)
    except (ProblemError, ObservationError) as exc:
        raise DatasetError(f"demonstration row {row}: {exc}") from None
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    return problem._replace(init_x=f32(data.init_x[row]), init_y=f32(data.init_y[row]), y_lb=f32(data.lane_bounds[row, 0]),
                            y_ub=f32(data.lane_bounds[row, 1]), observation=f32(data.observation[row]))


def mode_lanes(data: Demonstrations) -> np.ndarray:
    """(n,) distinct target lanes of each row's modes (:func:`driveopt.data.modes.lanes_per_row`), each row's road read
    from its lane bounds and the basis from the file's horizon and node count; DatasetError for a file without modes."""
    if data.modes is None:
        raise DatasetError("the demonstrations hold no modes (schema version 1): nothing to count")
    bounds, index = np.unique(data.lane_bounds, axis=0, return_inverse=True)
    roads = [road_from_bounds(float(lo), float(hi)) for lo, hi in bounds]
    index = index.reshape(-1)
    center0, width, lanes = (np.array([getattr(r, f) for r in roads])[index] for f in ("first_lane_center", "lane_width", "num_lanes"))
    basis = make_basis(BasisConfig(horizon=float(data.attrs.get("horizon", BasisConfig.horizon)),
                                   num_nodes=int(data.attrs.get("num_nodes", BasisConfig.num_nodes))))
    return lanes_per_row(data.modes.coeffs, data.modes.mask, basis, center0, width, lanes)
