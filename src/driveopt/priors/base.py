"""What every prior is: a JAX pytree with ``propose(problem, key, num, warm_mean) -> Proposal``.

A *prior* proposes the first batch of set-points ``p = (v_1..v_4 [m/s], y_1..y_4 [m])`` of a
planning call and the Gaussian ``N(mean, cov)`` that the sampler adapts from there. The planner
passes it through ``jit`` as data, so a learned prior carries its weights as leaves and slots in
without any change to the optimiser; its static fields (dataclass fields marked ``static``) are
part of the compiled function's key.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import jax
import jax.numpy as jnp

from driveopt.problem import PlanningProblem
from driveopt.qp import NUM_SEGMENTS


class Proposal(NamedTuple):
    samples: jnp.ndarray  # (num, 8) set-points
    mean: jnp.ndarray  # (8,) mean of the distribution they came from
    cov: jnp.ndarray  # (8, 8) its covariance


class Prior(Protocol):
    def propose(self, problem: PlanningProblem, key: jax.Array, num: int, warm_mean: jnp.ndarray | None) -> Proposal:
        """``num`` set-points; ``warm_mean`` None means :func:`default_mean` (a prior centred on the warm start
        centres on it; the planner passes that value for an absent ``WarmStart``)."""
        ...


def clip_setpoints(p: jnp.ndarray, problem: PlanningProblem, v_max: float) -> jnp.ndarray:
    """Keep speeds in [0, v_max] [m/s] and lateral set-points inside the lane bounds [m]."""
    v = jnp.clip(p[..., :NUM_SEGMENTS], 0.0, v_max)
    y = jnp.clip(p[..., NUM_SEGMENTS:], problem.y_lb, problem.y_ub)
    return jnp.concatenate([v, y], axis=-1)


def moments(samples: jnp.ndarray, jitter: float) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(mean (8,), covariance (8, 8)) of ``samples`` (num, 8), ``jitter`` added to the covariance diagonal."""
    mean = jnp.mean(samples, axis=0)
    centred = samples - mean
    cov = centred.T @ centred / samples.shape[0] + jitter * jnp.eye(samples.shape[1], dtype=samples.dtype)
    return mean, cov


def default_mean(problem: PlanningProblem) -> jnp.ndarray:
    """Current speed and lateral position, held over the horizon."""
    speed = jnp.hypot(problem.init_x[1], problem.init_y[1])
    return jnp.concatenate([jnp.full(NUM_SEGMENTS, speed), jnp.full(NUM_SEGMENTS, problem.init_y[0])])
