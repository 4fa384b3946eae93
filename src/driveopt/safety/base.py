"""What a safety filter is: a pytree that sets up the batch projection for every sampler batch (P2 §III-C).

``initialise(problem, coeffs) -> FilterInit`` sees the planning problem and the batch of set-point
QP solutions (B, 2n) and returns the barrier parameters and the projection's first iterate and
multipliers. :func:`driveopt.planner.solve` and :func:`~driveopt.planner.plan` take one as
``safety_filter``; like priors, a learned filter carries its weights as pytree leaves, so planners
and their compilation stay shared. Without one the projection starts from the QP solutions with
zero multipliers and ``gamma = 1`` (the plain constraints).
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import jax.numpy as jnp

from driveopt.problem import PlanningProblem


class FilterInit(NamedTuple):
    """How the projection of one batch starts (see :func:`driveopt.projection.project`)."""

    gamma_obs: jnp.ndarray  # () or (B, 1) [-] obstacle barrier parameter in (0, 1], per sample when (B, 1)
    gamma_lane: jnp.ndarray  # () [-] lane barrier parameter in (0, 1]
    coeffs: jnp.ndarray  # (B, 2n) first iterate
    multipliers: jnp.ndarray  # (B, 2n) initial Lagrange multipliers


class SafetyFilter(Protocol):
    def initialise(self, problem: PlanningProblem, coeffs: jnp.ndarray) -> FilterInit:
        ...
