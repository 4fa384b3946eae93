"""The 55-dim observation of a scene: the learned components' input (DESIGN §2.5).

:func:`observation_vector` gives float32, shape ``(5 + 5 * num_neighbours,)`` = (55,) by default::

    [y_ub - y_ego, y_lb - y_ego, vx_ego, vy_ego, heading_ego,
     dx_1, dy_1, vx_1, vy_1, heading_1, ..., dx_10, dy_10, vx_10, vy_10, heading_10]

``y_lb``/``y_ub`` are the bounds of the ego centre that keep its box on the road
(``Scene.lateral_bounds``, the planner's lane constraint); ``(dx, dy)`` are positions relative
to the ego [m]; velocities [m/s] are in the road frame (not relative); headings [rad] are the
directions of motion relative to the road (``EgoState.heading``, ``Neighbour.heading``).
Neighbours are the ``num_neighbours`` nearest by Euclidean distance (the order ``build_problem``
uses), nearest first; missing ones are padding rows ``(DUMMY_DX, 0, 0, 0, 0)`` (placed
:data:`DUMMY_DX` ahead on the ego's line, at rest), after every real one. :func:`neighbour_mask`
is the one place that tells padding from a real neighbour. ``build_problem`` stores the vector as
``PlanningProblem.observation``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from driveopt.errors import DriveoptError
from driveopt.prediction import nearest_neighbours
from driveopt.scene import Scene

NUM_NEIGHBOURS = 10  # [-] neighbours in the observation (both papers)
EGO_FEATURES = 5  # [-] y_ub - y, y_lb - y, vx, vy, heading
NEIGHBOUR_FEATURES = 5  # [-] dx, dy, vx, vy, heading
OBSERVATION_DIM = EGO_FEATURES + NEIGHBOUR_FEATURES * NUM_NEIGHBOURS  # 55
DUMMY_DX = 1000.0  # [m] padding neighbours sit this far ahead of the ego: beyond any 15 s plan (30 m/s * 15 s)
PADDING_ROW = np.array([DUMMY_DX, 0.0, 0.0, 0.0, 0.0], dtype=np.float32)  # [m, m, m/s, m/s, rad] a missing neighbour


class ObservationError(DriveoptError):
    """The simulator state or an observation is malformed (wrong shape, NaN, unsupported road)."""


def observation_vector(scene: Scene, num_neighbours: int = NUM_NEIGHBOURS) -> np.ndarray:
    """(5 + 5 * num_neighbours,) float32 observation of a scene; see the module docstring for the layout."""
    if not isinstance(scene, Scene):
        raise ObservationError(f"observation_vector needs a Scene, got {type(scene).__name__}")
    if not isinstance(num_neighbours, int) or num_neighbours < 1:
        raise ObservationError(f"num_neighbours must be an int >= 1, got {num_neighbours!r}")
    ego = scene.ego
    y_lb, y_ub = scene.lateral_bounds
    obs = np.empty(EGO_FEATURES + NEIGHBOUR_FEATURES * num_neighbours, dtype=np.float64)
    obs[:EGO_FEATURES] = (y_ub - ego.y, y_lb - ego.y, ego.vx, ego.vy, ego.heading)
    rows = obs[EGO_FEATURES:].reshape(num_neighbours, NEIGHBOUR_FEATURES)
    rows[:] = PADDING_ROW
    for i, n in enumerate(nearest_neighbours(scene, num_neighbours)):
        rows[i] = (n.x - ego.x, n.y - ego.y, n.vx, n.vy, n.heading)
    obs = obs.astype(np.float32)
    check_observation(obs, num_neighbours)
    return obs


def check_observation(obs: Any, num_neighbours: int = NUM_NEIGHBOURS) -> None:
    """Raise ObservationError unless ``obs`` is a finite vector (or batch of vectors) of the right length."""
    arr = np.asarray(obs)
    expected = EGO_FEATURES + NEIGHBOUR_FEATURES * num_neighbours
    if arr.ndim not in (1, 2) or arr.shape[-1] != expected:
        raise ObservationError(f"observation must have shape ({expected},) or (batch, {expected}), got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number):
        raise ObservationError(f"observation must be numeric, got dtype {arr.dtype}")
    bad = ~np.isfinite(arr)
    if np.any(bad):
        index = np.argwhere(bad)[0]
        raise ObservationError(f"observation has a non-finite entry at index {tuple(int(i) for i in index)}")


def split_observation(obs: Any, num_neighbours: int = NUM_NEIGHBOURS) -> tuple[np.ndarray, np.ndarray]:
    """(ego (..., 5), neighbours (..., num_neighbours, 5)) views of a checked observation."""
    check_observation(obs, num_neighbours)
    arr = np.asarray(obs)
    return arr[..., :EGO_FEATURES], arr[..., EGO_FEATURES:].reshape(*arr.shape[:-1], num_neighbours, NEIGHBOUR_FEATURES)


def neighbour_mask(obs: Any) -> Any:
    """(..., num_neighbours) bool, True for a real neighbour row of an observation (..., 5 + 5 * n).

    Works on numpy and JAX arrays alike (the CVAE's features use it under jit).
    """
    rows = obs[..., EGO_FEATURES:].reshape(*obs.shape[:-1], -1, NEIGHBOUR_FEATURES)
    return ~(rows == PADDING_ROW).all(axis=-1)


def is_dummy(neighbours: np.ndarray) -> np.ndarray:
    """(..., num_neighbours) True where a neighbour row of :func:`split_observation` is padding."""
    return (np.asarray(neighbours) == PADDING_ROW).all(axis=-1)
