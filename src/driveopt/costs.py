"""Upper-level driving cost c_u (P1 §V) as named terms.

Each term is a mean over the time nodes so that weights do not depend on the node count, but ``lane_flow``, which reads
a plan's end (:func:`lane_flow`).
"""

from __future__ import annotations

import jax.numpy as jnp

from driveopt.config import CostConfig
from driveopt.problem import PlanningProblem
from driveopt.trajectory import Trajectory

COST_TERMS = ("speed", "lateral_acceleration", "heading", "curvature", "lane_centering", "consistency", "route",
              "lane_flow")
FLOW_REACH = 40.0  # [m] how far beyond the end of a plan kept at v_des a car still counts for its lane's flow
MIN_FLOW_SPEED = 0.5  # [m/s] a car moving along the road more slowly than this (standing, oncoming) is no lane's flow
MAX_FLOW_LATERAL_SPEED = 0.5  # [m/s] nor is one moving across the lanes faster than this (crossing, changing lanes)


def nearest_lane_center(problem: PlanningProblem, y: jnp.ndarray) -> jnp.ndarray:
    """[m] centre of the lane nearest to each lateral position y."""
    index = jnp.clip(jnp.round((y - problem.lane_center0) / problem.lane_width), 0, problem.num_lanes - 1)
    return problem.lane_center0 + index * problem.lane_width


def outside_band(band: jnp.ndarray, y: jnp.ndarray) -> jnp.ndarray:
    """[m] how far each lateral position y lies outside ``band`` = (low, high) (0 inside)."""
    return jnp.maximum(band[0] - y, 0.0) + jnp.maximum(y - band[1], 0.0)


def time_weighted_mean(values: jnp.ndarray, t: jnp.ndarray, time_constant: float) -> jnp.ndarray:
    """(...,) mean of ``values`` (..., K) over the nodes at times ``t`` [s], node t weighed exp(-t / time_constant)
    [s]; 0: the plain mean."""
    if time_constant == 0.0:
        return jnp.mean(values, axis=-1)
    weights = jnp.exp(-(t - t[..., :1]) / time_constant)
    return jnp.sum(weights * values, axis=-1) / jnp.sum(weights, axis=-1)


def speed_reference(traj: Trajectory, problem: PlanningProblem) -> jnp.ndarray:
    """[m/s] the speed each node of a plan is asked for: the plan's start speed, at most ``problem.slowing_from``, less
    ``problem.slowing`` [m/s^2] times the time since the start, down to ``problem.v_des`` (``slowing_from`` at or below
    ``v_des``: ``v_des`` throughout, exactly)."""
    start = jnp.minimum(traj.speed[..., :1], problem.slowing_from)
    return jnp.maximum(problem.v_des, start - problem.slowing * (traj.t - traj.t[..., :1]))


def lane_flow(traj: Trajectory, problem: PlanningProblem) -> jnp.ndarray:
    """(...,) [-] ((v_des - v) / v_des)^2 where v [m/s] is the slowest speed along the road, at the horizon's end, of
    the cars moving along the lane in which the plan ends, ahead of its end and within :data:`FLOW_REACH` of where a
    plan kept at v_des would end; 0 where there is none or none is slower than v_des.

    The speed that lane lets the car keep after the horizon: a plan ending behind a slower car pays for the speed it
    will lose later, which a speed term over the horizon cannot see, so the car changes to a faster lane while the
    slower car is still far ahead (where overtaking is cheap) rather than once it is close behind it."""
    x_end, y_end = traj.x[..., -1:], traj.y[..., -1:]
    step = (traj.t[..., -1] - traj.t[..., -2])[..., None]  # [s]
    obstacle_x, obstacle_y = problem.obstacle_x, problem.obstacle_y  # (N, K)
    speed = (obstacle_x[:, -1] - obstacle_x[:, -2]) / step  # (..., N) [m/s] along the road at the horizon's end
    lateral_speed = jnp.abs(obstacle_y[:, -1] - obstacle_y[:, -2]) / step
    along = (speed > MIN_FLOW_SPEED) & (lateral_speed < MAX_FLOW_LATERAL_SPEED) & (problem.obstacle_mask > 0)
    in_lane = jnp.abs(obstacle_y[:, -1] - nearest_lane_center(problem, y_end)) < 0.5 * problem.lane_width
    reach = problem.v_des * traj.t[..., -1:] + FLOW_REACH
    ahead = (obstacle_x[:, -1] > x_end) & (obstacle_x[:, -1] < reach)
    slowest = jnp.min(jnp.where(along & in_lane & ahead, speed, problem.v_des), axis=-1)
    return (jnp.maximum(problem.v_des - slowest, 0.0) / jnp.maximum(problem.v_des, 1.0)) ** 2


def cost_terms(traj: Trajectory, problem: PlanningProblem, previous_y: jnp.ndarray | None = None,
               time_constant: float = 0.0) -> dict[str, jnp.ndarray]:
    """Unweighted cost terms, each (...,): means over the nodes, node t weighed exp(-t / ``time_constant``) [s]
    (:attr:`CostConfig.time_constant`; 0: the plain mean), and :func:`lane_flow`; the speed term's reference:
    :func:`speed_reference`.

    previous_y: (K,) or per row (..., K) [m] lateral positions of the previous replan's plan at these nodes' times; the
    ``consistency`` term is zero without it.
    """
    lane_offset = traj.y - nearest_lane_center(problem, traj.y)
    # Curvature is only meaningful when moving; cap its influence at crawling speeds.
    curvature = jnp.clip(traj.curvature, -1.0, 1.0)
    per_node = {
        "speed": (traj.speed - speed_reference(traj, problem)) ** 2,
        "lateral_acceleration": traj.ay**2,
        "heading": traj.heading**2,
        "curvature": curvature**2,
        "lane_centering": lane_offset**2,
        # in whole lanes (the nearest lane's): a plan part way to the next lane gains nothing from it, so it costs more
        # than one centred in either
        "route": jnp.round(outside_band(problem.pull_band, traj.y) / problem.lane_width),
    }
    if previous_y is not None:
        per_node["consistency"] = (traj.y - previous_y) ** 2
    terms = {name: time_weighted_mean(value, traj.t, time_constant) for name, value in per_node.items()}
    terms.setdefault("consistency", jnp.zeros(traj.y.shape[:-1]))
    terms["lane_flow"] = lane_flow(traj, problem)
    return {name: terms[name] for name in COST_TERMS}


def weighted_cost(terms: dict[str, jnp.ndarray], weights: CostConfig) -> jnp.ndarray:
    """Sum of the weighted terms (...,)."""
    return sum(getattr(weights, name) * terms[name] for name in COST_TERMS)
