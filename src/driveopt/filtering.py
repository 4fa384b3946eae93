"""What a safety filter is: a pytree that sets up the batch projection for every sampler batch (P2 §III-C).

``initialise(problem, coeffs) -> FilterInit`` sees the planning problem and the batch of set-point
QP solutions (B, 2n) and returns the barrier parameters and the projection's first iterate and
multipliers. :func:`driveopt.planner.solve` and :func:`~driveopt.planner.plan` take one as
``safety_filter``; like priors, a learned filter carries its weights as pytree leaves, so planners
and their compilation stay shared. Without one the projection starts from the QP solutions with
zero multipliers and the configuration's ``gamma_obs`` / ``gamma_lane`` (1 by default: the plain
constraints). :func:`check_filter_init` refuses malformed outputs when the planner is traced.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import jax.numpy as jnp

from driveopt.errors import DriveoptError
from driveopt.problem import PlanningProblem


class FilterError(DriveoptError):
    """A safety filter (or its weights) that cannot serve this planner: outputs of the wrong shape, another basis."""


class FilterInit(NamedTuple):
    """How the projection of one batch starts (see :func:`driveopt.projection.project`)."""

    gamma_obs: jnp.ndarray  # () or (B,) [-] obstacle barrier parameter in (0, 1], per sample when (B,) (or (B, 1))
    gamma_lane: jnp.ndarray  # () or (B,) [-] lane barrier parameter in (0, 1], likewise
    coeffs: jnp.ndarray  # (B, 2n) first iterate
    multipliers: jnp.ndarray  # (B, 2n) initial Lagrange multipliers


class SafetyFilter(Protocol):
    def initialise(self, problem: PlanningProblem, coeffs: jnp.ndarray) -> FilterInit:
        ...


def check_filter_init(init: FilterInit, coeffs_shape: tuple[int, int]) -> FilterInit:
    """``init`` when its shapes fit a batch of coefficients ``coeffs_shape`` (B, 2n); FilterError naming the
    wrong field otherwise (shapes are static, so this runs once, when the planner is traced)."""
    if not isinstance(init, FilterInit):
        raise FilterError(f"a safety filter's initialise must return a FilterInit, got {type(init).__name__}")
    B = coeffs_shape[0]
    for name in ("gamma_obs", "gamma_lane"):
        shape = jnp.shape(getattr(init, name))
        if shape not in ((), (B,), (B, 1)):
            raise FilterError(f"safety filter: {name} has shape {shape}; it must be a number or one per sample ({B},)")
    for name in ("coeffs", "multipliers"):
        shape = jnp.shape(getattr(init, name))
        if shape != tuple(coeffs_shape):
            raise FilterError(f"safety filter: {name} has shape {shape}; the batch's coefficients are {tuple(coeffs_shape)}")
    return init
