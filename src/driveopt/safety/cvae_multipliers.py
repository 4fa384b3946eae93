"""The multiplier head of [5]'s CVAE (P2's CVAE baseline) as the planner's safety filter.

:class:`CVAEMultipliers` is a :class:`~driveopt.filtering.SafetyFilter`: for every batch it returns, per row, the
multipliers the head predicts from the observation and that row's set-point-QP trajectory
(:func:`driveopt.learned.cvae_multipliers.multipliers`), the row itself as first iterate (as [5]), and the
configuration's barrier parameters (``gamma_obs`` / ``gamma_lane``: 1, the plain constraints, unless the planner is
in barrier mode). A row's multipliers depend on nothing but its own trajectory, so they stay paired with the
set-points that made it, whichever batch and position it has. The set-points come from the same checkpoint's
decoder (:mod:`driveopt.priors.cvae_multipliers`).

Without weights (given or shipped) the filter is None: the projection starts from zero multipliers (the prior warns once for both).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax.numpy as jnp

from driveopt.config import PlannerConfig
from driveopt.filtering import FilterInit
from driveopt.problem import PlanningProblem
from driveopt.pytree import pytree_dataclass, static


@pytree_dataclass
class CVAEMultipliers:
    """Initial multipliers from a cvae-multipliers model (a :mod:`~driveopt.pytree` dataclass)."""

    params: Any
    normaliser: Any  # driveopt.learned.cvae_multipliers.Normaliser
    config: Any = static()  # driveopt.learned.cvae_multipliers.MultiplierCVAEConfig
    gamma_obs: float = static(1.0)  # [-] the projection's, passed through
    gamma_lane: float = static(1.0)  # [-]

    def initialise(self, problem: PlanningProblem, coeffs) -> FilterInit:
        from driveopt.learned.cvae_multipliers import multipliers

        lam = multipliers(self.params, self.config, self.normaliser, problem, coeffs)
        return FilterInit(jnp.asarray(self.gamma_obs, coeffs.dtype), jnp.asarray(self.gamma_lane, coeffs.dtype), coeffs, lam)


def load_multipliers(path: str | Path, config: PlannerConfig, lanes: int | None = None) -> CVAEMultipliers:
    """The filter of the checkpoint ``path`` for a planner of configuration ``config``; CheckpointError when unusable
    or (with ``lanes``) trained for another road."""
    from driveopt.learned.cvae_multipliers import load_model

    cfg, params, norm, _ = load_model(path, lanes)
    return CVAEMultipliers(params, norm, cfg, config.projection.gamma_obs, config.projection.gamma_lane)


def filter_for(config: PlannerConfig, lanes: int, weights: str | Path | None) -> CVAEMultipliers | None:
    """The filter from ``weights`` (or the weights shipped for ``lanes``), or None without any (zero multipliers; the
    prior's factory warns)."""
    from driveopt.learned.cvae_multipliers import weights_file

    path = weights_file(lanes, weights)
    return load_multipliers(path, config, lanes) if path else None
