"""The set-points of [5]'s CVAE (P2's CVAE baseline) as the planner's first proposal; loading its weights.

``MultiplierCVAEPrior.propose`` draws z ~ N(0, I) and decodes set-points for the problem's observation
(:func:`driveopt.learned.cvae_multipliers.sample_setpoints`), clipped to the planner's bounds; its mean and covariance
initialise the sampler's Gaussian for any later iteration, as for any prior. The other half of the model, the
multiplier head, is the safety filter :class:`driveopt.safety.cvae_multipliers.CVAEMultipliers`, loaded from the
same checkpoint: it computes each row's initial multipliers from that row's set-point-QP trajectory, so every
sample's multipliers stay paired with its own set-points.

Weights ship for four-lane roads (``weights/cvae-multipliers-four-lane.ckpt``; ``driveopt train cvae-multipliers``
writes others): on other roads, without ``--weights``, the ``cvae-multipliers`` planner warns and plans with the
configuration's Gaussian prior and zero multipliers. Checkpoints record the lane counts of their training roads;
weights trained for another lane count are refused.

Flax is imported when weights are loaded or run, not with this module.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

from driveopt.config import PlannerConfig, ProjectionConfig
from driveopt.pytree import pytree_dataclass, static
from driveopt.sampler import GaussianPrior, Proposal, clip_setpoints, moments

COVARIANCE_JITTER = 0.01  # [-] added to the diagonal of the proposal's covariance (as the CVAE prior's)


@pytree_dataclass
class MultiplierCVAEPrior:
    """First proposal from the set-point decoder of a cvae-multipliers model (a :mod:`~driveopt.pytree` dataclass)."""

    params: Any
    normaliser: Any  # driveopt.learned.cvae_multipliers.Normaliser
    config: Any = static()  # driveopt.learned.cvae_multipliers.MultiplierCVAEConfig
    v_max: float = static(ProjectionConfig.v_max)  # [m/s] planner's speed bound

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        from driveopt.learned.cvae_multipliers import sample_setpoints

        samples = clip_setpoints(sample_setpoints(self.params, self.config, self.normaliser, problem, key, num), problem, self.v_max)
        return Proposal(samples, *moments(samples, COVARIANCE_JITTER))


def load_prior(path: str | Path, v_max: float = ProjectionConfig.v_max, lanes: int | None = None) -> MultiplierCVAEPrior:
    """The prior of the checkpoint ``path``; CheckpointError when unusable or (with ``lanes``) for another road."""
    from driveopt.learned.cvae_multipliers import load_model

    cfg, params, norm, _ = load_model(path, lanes)
    return MultiplierCVAEPrior(params, norm, cfg, float(v_max))


def missing_weights_notice(lanes: int) -> str:
    return (f"no cvae-multipliers weights shipped for {lanes}-lane roads (train them with `driveopt train "
            "cvae-multipliers` and pass --weights): planning from the Gaussian start with zero multipliers instead")


def prior_for(config: PlannerConfig, lanes: int, weights: str | Path | None) -> Any:
    """The decoder's prior from ``weights`` (or the weights shipped for ``lanes``); without any, the configuration's
    Gaussian prior, with a warning."""
    from driveopt.learned.cvae_multipliers import weights_file

    path = weights_file(lanes, weights)
    if path is None:
        warnings.warn(missing_weights_notice(lanes), stacklevel=2)
        return GaussianPrior.from_config(config.sampler, config.projection.v_max)
    return load_prior(path, config.projection.v_max, lanes=lanes)


def cvae_multipliers_prior():
    """Prior factory of the registry's cvae-multipliers planners: ``(config, lanes, weights) -> prior``
    (:func:`prior_for`), made as the other learned priors' factories are."""
    return prior_for
