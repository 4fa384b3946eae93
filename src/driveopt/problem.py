"""The array form of a scene that the planner consumes: :class:`PlanningProblem`, built and checked.

:func:`build_problem` puts the ego at x = 0 (the planning frame), predicts the
``max_obstacles`` most relevant neighbours over the horizon (:mod:`driveopt.prediction`; masked padding when
fewer), sizes their collision ellipses, and stores the 55-dim observation
(:mod:`driveopt.observation`) for learned priors. :func:`check_problem` refuses wrong shapes and
non-finite values.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from driveopt.config import BasisConfig, check_obstacles
from driveopt.goal import Goal
from driveopt.observation import OBSERVATION_DIM, observation_vector
from driveopt.prediction import (
    BRAKING_TIME,
    SELECTION_TIME,
    ego_box_growth,
    ellipse_semi_axes,
    obstacle_slots,
    predict_neighbour,
)
from driveopt.scene import CURVATURE_CELLS, EgoState, ProblemError, Scene

NO_PULL = (-1e4, 1e4)  # [m] PlanningProblem.pull_band without a band to draw plans towards: wider than any road


class PlanningProblem(NamedTuple):
    """Array form of a scene in the planning frame (ego at x = 0). A JAX pytree.

    Shapes: N obstacles, K time nodes, C = :data:`~driveopt.scene.CURVATURE_CELLS` cells of the road ahead.
    """

    init_x: jnp.ndarray  # (3,) [m, m/s, m/s^2] x, x', x'' at t = 0
    init_y: jnp.ndarray  # (3,) [m, m/s, m/s^2] y, y', y'' at t = 0
    y_lb: jnp.ndarray  # () [m] lower bound of the ego centre
    y_ub: jnp.ndarray  # () [m] upper bound of the ego centre
    lane_center0: jnp.ndarray  # () [m] centre of the lowest lane
    lane_width: jnp.ndarray  # () [m]
    num_lanes: jnp.ndarray  # () [-] as float
    road_curvature: jnp.ndarray  # (C,) [1/m] the sharpest signed road curvature in each CURVATURE_CELL [m] cell ahead of x = 0
    # (:attr:`driveopt.scene.Road.curvature_ahead`): the centripetal bound at a node reads the cell of its position
    road_origin: jnp.ndarray  # () [m] y of the line that curvature is of (:attr:`driveopt.scene.Road.curvature_origin`)
    v_des: jnp.ndarray  # () [m/s]
    slowing: jnp.ndarray  # () [m/s^2] the rate at which the speed asked for comes down from slowing_from to v_des
    slowing_from: jnp.ndarray  # () [m/s] the most asked for at t = 0 where above v_des (driveopt.costs.speed_reference)
    pull_band: jnp.ndarray  # (2,) [m] (low, high) of the ego centre that the ``route`` cost term draws plans towards:
    # a widened goal's band ahead (:meth:`driveopt.goal.Goal.pull_band`); :data:`NO_PULL` without one (the term is 0)
    obstacle_x: jnp.ndarray  # (N, K) [m] predicted centres
    obstacle_y: jnp.ndarray  # (N, K) [m]
    obstacle_a: jnp.ndarray  # (N,) [m] longitudinal semi-axis of the collision ellipse
    obstacle_b: jnp.ndarray  # (N,) [m] lateral semi-axis
    obstacle_mask: jnp.ndarray  # (N,) 1.0 for a real obstacle, 0.0 for padding
    ellipse_growth: jnp.ndarray  # (2, K) [m] added to every ellipse's (longitudinal, lateral) semi-axis per node: the ego turned
    ego_heading: jnp.ndarray  # () [rad] heading of the ego's box now (:func:`box_heading`), whose growth ellipse_growth[:, 0] is
    observation: jnp.ndarray  # (55,) the learned priors' input (driveopt.observation)


def box_heading(ego: EgoState) -> float:
    """[rad] heading of the ego's box (:attr:`EgoState.box_heading`) within [-pi/2, pi/2]: a box turned by half a turn
    is the same box, so a reversing car, whose direction of travel is near pi, is along the road, not turned across
    it (its turned-box growth fades from its body's turn, not through pi/2 on the way from pi to 0). Headings within
    the interval are returned unchanged."""
    heading = ego.box_heading
    return heading - math.pi * round(heading / math.pi)


def travel_direction(problem: PlanningProblem) -> jnp.ndarray:
    """() [-] the ego's direction of travel along the road: -1.0 when it reverses (vx < 0), else 1.0 (standing too).

    A stop continues the motion the car has and brakes it to rest (:mod:`driveopt.fallback`), and no plan moves against
    this direction (the projection's course bound, :mod:`driveopt.projection`)."""
    return jnp.where(problem.init_x[1] < 0.0, -1.0, 1.0).astype(problem.init_x.dtype)


def build_problem(
    scene: Scene, basis: BasisConfig = BasisConfig(), max_obstacles: int = 10, ignore_followers: bool = False,
    braking_time: float = BRAKING_TIME, selection_time: float = SELECTION_TIME, goal: Goal | None = None,
    time: float = 0.0,
) -> PlanningProblem:
    """Turn a scene into the planner's arrays, in the frame where the ego starts at x = 0.

    ignore_followers: leave out same-lane vehicles behind the ego. Constant-velocity prediction
    drives a faster follower straight through a slow ego, which no plan can avoid, whereas
    car-following traffic (IDM) brakes for the vehicle ahead of it.
    braking_time: [s] how long a braking neighbour is predicted to keep braking (0: constant velocity, P1).
    selection_time: [s] the ``max_obstacles`` planned against are those that come closest to the ego
    within this time (0: the nearest now, P1); see :func:`driveopt.prediction.relevant_neighbours`.
    goal: where the plan should lead (:class:`driveopt.goal.Goal`): its band narrows ``y_lb, y_ub`` once it is near,
    the band is then the one lane of the lane terms; its speed and time windows set ``v_des`` (one they lower is asked
    for at once: no ``scene.slowing_from``); ``time`` [s] is the episode's clock, which the goal's time window reads.
    None: the scene's bounds and ``v_des``, exactly.
    ConfigError for more than :data:`driveopt.config.MAX_OBSTACLES` unless ``DRIVEOPT_ALLOW_LARGE=1``.
    """
    if not isinstance(scene, Scene):
        raise ProblemError(f"build_problem needs a Scene, got {type(scene).__name__}")
    if max_obstacles < 1:
        raise ProblemError("max_obstacles must be >= 1")
    check_obstacles(max_obstacles)  # before its (max_obstacles, nodes) arrays are allocated
    t = np.linspace(0.0, basis.horizon, basis.num_nodes)
    ego = scene.ego
    body = dataclasses.replace(ego, yaw=box_heading(ego))  # the same box, its heading within [-pi/2, pi/2]
    y_lb, y_ub = scene.lateral_bounds
    v_des = scene.v_des
    lanes = (scene.road.first_lane_center, scene.road.lane_width, scene.road.num_lanes)
    pull = NO_PULL
    if goal is not None:
        if not isinstance(goal, Goal):
            raise ProblemError(f"goal must be a driveopt.goal.Goal, got {type(goal).__name__}")
        y_lb, y_ub = goal.lateral_bounds(scene)
        v_des = goal.desired_speed(scene, time)
        lanes = goal.lanes(scene, (y_lb, y_ub))
        pull = goal.pull_band(scene, (y_lb, y_ub)) or NO_PULL
    K, N = basis.num_nodes, max_obstacles
    # Padding: far behind the ego, masked out; values stay moderate for float32.
    ox = np.full((N, K), -1000.0)
    oy = np.full((N, K), 0.5 * (y_lb + y_ub))
    oa = np.ones(N)
    ob = np.ones(N)
    mask = np.zeros(N)
    for i, (n, nodes) in enumerate(obstacle_slots(scene, t, N, ignore_followers, selection_time, braking_time)):
        px, py = predict_neighbour(n, t, scene.road.edges, braking_time)
        ox[i], oy[i] = px - ego.x, py
        if nodes is not None:  # a phase of a turning path: elsewhere far behind, as padding
            ox[i, ~nodes], oy[i, ~nodes] = -1000.0, 0.5 * (y_lb + y_ub)
        oa[i], ob[i] = ellipse_semi_axes(ego, n, scene.ellipse_margin)
        mask[i] = 1.0
    f32 = lambda v: jnp.asarray(v, dtype=jnp.float32)  # noqa: E731
    return PlanningProblem(
        init_x=f32([0.0, ego.vx, ego.ax]),
        init_y=f32([ego.y, ego.vy, ego.ay]),
        y_lb=f32(y_lb),
        y_ub=f32(y_ub),
        lane_center0=f32(lanes[0]),
        lane_width=f32(lanes[1]),
        num_lanes=f32(lanes[2]),
        road_curvature=f32(scene.road.curvature_profile),
        road_origin=f32(scene.road.curvature_origin),
        v_des=f32(v_des),
        slowing=f32(scene.slowing),
        slowing_from=f32(scene.slowing_from if v_des >= scene.v_des else 0.0),  # a goal that lowers v_des: at once
        pull_band=f32(pull),
        obstacle_x=f32(ox),
        obstacle_y=f32(oy),
        obstacle_a=f32(oa),
        obstacle_b=f32(ob),
        obstacle_mask=f32(mask),
        ellipse_growth=f32(ego_box_growth(body, t)),
        ego_heading=f32(body.box_heading),
        observation=f32(observation_vector(scene)),
    )


def ellipse_axes(problem: PlanningProblem) -> tuple[jnp.ndarray, jnp.ndarray]:
    """[m] (N, K) longitudinal and lateral semi-axes of every obstacle's collision ellipse at every node."""
    return (problem.obstacle_a[:, None] + problem.ellipse_growth[0], problem.obstacle_b[:, None] + problem.ellipse_growth[1])


def check_problem(problem: PlanningProblem, basis: BasisConfig = BasisConfig()) -> None:
    """Raise ProblemError unless every array of ``problem`` is finite and has the right shape."""
    if not isinstance(problem, PlanningProblem):
        raise ProblemError(f"expected a PlanningProblem, got {type(problem).__name__}")
    K = basis.num_nodes
    N = np.shape(problem.obstacle_x)[0] if np.ndim(problem.obstacle_x) == 2 else -1
    expected = {
        "init_x": (3,), "init_y": (3,), "y_lb": (), "y_ub": (), "lane_center0": (), "lane_width": (),
        "num_lanes": (), "road_curvature": (CURVATURE_CELLS,), "road_origin": (), "v_des": (), "slowing": (),
        "slowing_from": (), "pull_band": (2,),
        "obstacle_x": (N, K), "obstacle_y": (N, K),
        "obstacle_a": (N,), "obstacle_b": (N,), "obstacle_mask": (N,), "ellipse_growth": (2, K),
        "ego_heading": (),
        "observation": (OBSERVATION_DIM,),
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
    if not float(problem.pull_band[0]) <= float(problem.pull_band[1]):
        raise ProblemError("problem.pull_band must be (low, high) with low <= high")
    if np.any(np.asarray(problem.obstacle_a) <= 0) or np.any(np.asarray(problem.obstacle_b) <= 0):
        raise ProblemError("obstacle ellipse semi-axes must be > 0")
    if np.any(np.asarray(problem.ellipse_growth) < 0):
        raise ProblemError("problem.ellipse_growth must be >= 0")
