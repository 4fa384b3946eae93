"""Upper-level driving cost c_u (P1 §V) as named terms.

Each term is a mean over the time nodes so that weights do not depend on the node count.
"""

from __future__ import annotations

import jax.numpy as jnp

from driveopt.config import CostConfig
from driveopt.problem import PlanningProblem
from driveopt.trajectory import Trajectory

COST_TERMS = ("speed", "lateral_acceleration", "heading", "curvature", "lane_centering", "consistency", "route")


def nearest_lane_center(problem: PlanningProblem, y: jnp.ndarray) -> jnp.ndarray:
    """[m] centre of the lane nearest to each lateral position y."""
    index = jnp.clip(jnp.round((y - problem.lane_center0) / problem.lane_width), 0, problem.num_lanes - 1)
    return problem.lane_center0 + index * problem.lane_width


def outside_band(band: jnp.ndarray, y: jnp.ndarray) -> jnp.ndarray:
    """[m] how far each lateral position y lies outside ``band`` = (low, high) (0 inside)."""
    return jnp.maximum(band[0] - y, 0.0) + jnp.maximum(y - band[1], 0.0)


def cost_terms(traj: Trajectory, problem: PlanningProblem, previous_y: jnp.ndarray | None = None) -> dict[str, jnp.ndarray]:
    """Unweighted cost terms, each (...,): means over the nodes.

    previous_y: (K,) or per row (..., K) [m] lateral positions of the previous replan's plan at these nodes' times; the
    ``consistency`` term is zero without it.
    """
    lane_offset = traj.y - nearest_lane_center(problem, traj.y)
    # Curvature is only meaningful when moving; cap its influence at crawling speeds.
    curvature = jnp.clip(traj.curvature, -1.0, 1.0)
    return {
        "speed": jnp.mean((traj.speed - problem.v_des) ** 2, axis=-1),
        "lateral_acceleration": jnp.mean(traj.ay**2, axis=-1),
        "heading": jnp.mean(traj.heading**2, axis=-1),
        "curvature": jnp.mean(curvature**2, axis=-1),
        "lane_centering": jnp.mean(lane_offset**2, axis=-1),
        "consistency": jnp.zeros(traj.y.shape[:-1]) if previous_y is None else jnp.mean((traj.y - previous_y) ** 2, axis=-1),
        # in whole lanes (the nearest lane's): a plan part way to the next lane gains nothing from it, so it costs more
        # than one centred in either
        "route": jnp.mean(jnp.round(outside_band(problem.pull_band, traj.y) / problem.lane_width), axis=-1),
    }


def weighted_cost(terms: dict[str, jnp.ndarray], weights: CostConfig) -> jnp.ndarray:
    """Sum of the weighted terms (...,)."""
    return sum(getattr(weights, name) * terms[name] for name in COST_TERMS)
