"""The CVAE prior: the bi-level sampler's first proposal from the learned CVAE (P1 §III-D); shipped weights.

``CVAEPrior.propose`` draws z ~ N(0, I), decodes set-points for the problem's observation, and
initialises the sampler's Gaussian with their mean and covariance; later iterations adapt it as
for any prior. The CVAE replaces the warm start (``warm_mean`` is not used).

Checkpoints record the lane counts of the roads they were trained on; :func:`prior_for` refuses
weights trained for another lane count than the scenario's (checkpoints without the record, from
before it was kept, are accepted unchecked).

The network (:mod:`driveopt.learned.cvae`, Flax) is imported when a CVAE is loaded or sampled, not
with this module: the registry names the CVAE planners without every command importing Flax.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from driveopt.config import PlannerConfig, ProjectionConfig
from driveopt.files import shipped_weights_file
from driveopt.pytree import pytree_dataclass, static
from driveopt.sampler import GaussianPrior, Proposal, clip_setpoints, moments

COVARIANCE_JITTER = 0.01  # [-] added to the diagonal of the proposal's covariance
SHIPPED = {2: "cvae-two-lane.ckpt", 4: "cvae-four-lane.ckpt"}  # lanes -> file in driveopt/weights


@pytree_dataclass
class CVAEPrior:
    """First proposal from the CVAE; with ``gaussian_fraction`` > 0 that share of the batch comes from
    ``gaussian`` instead (a prior of :mod:`driveopt.sampler`, centred on the warm start).

    P1 draws the whole batch from the CVAE (``gaussian_fraction = 0``). Its samples stay around the
    expert's choice (mostly one lane, about 3 m/s of spread in speed), so where that choice is
    blocked hardly any sample projects to a feasible plan, the optimiser keeps the stopping plans and
    can stay stopped; the Gaussian share keeps the behaviours around the current motion in every batch.
    """

    params: Any
    normaliser: Any  # driveopt.learned.cvae.Normaliser
    config: Any = static()  # driveopt.learned.cvae.CVAEConfig
    v_max: float = static(ProjectionConfig.v_max)  # [m/s] planner's speed bound
    gaussian: Any = None
    gaussian_fraction: float = static(0.0)  # [-]

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        from driveopt.learned.cvae import sample_setpoints

        k_cvae, k_gauss = jax.random.split(key)
        mixed = int(round(self.gaussian_fraction * num)) if self.gaussian is not None else 0
        lane_bounds = jnp.stack([problem.y_lb, problem.y_ub])
        samples = sample_setpoints(self.params, self.config, self.normaliser, problem.observation, lane_bounds, k_cvae, num - mixed)
        if mixed:
            samples = jnp.concatenate([samples, self.gaussian.propose(problem, k_gauss, mixed, warm_mean).samples])
        samples = clip_setpoints(samples, problem, self.v_max)
        return Proposal(samples, *moments(samples, COVARIANCE_JITTER))


def load_prior(path: str | Path, v_max: float = ProjectionConfig.v_max, gaussian: Any = None, gaussian_fraction: float = 0.0,
               lanes: int | None = None) -> CVAEPrior:
    """The prior of the checkpoint ``path``; with ``lanes``, CheckpointError when the checkpoint records that
    it was trained for roads with other lane counts (see :func:`driveopt.learned.checkpoint.check_lanes`)."""
    from driveopt.learned.cvae import load_cvae

    cfg, params, norm, _ = load_cvae(path, lanes)
    return CVAEPrior(params, norm, cfg, float(v_max), gaussian, float(gaussian_fraction))


def shipped_weights(lanes: int) -> Path | None:
    """Path of the CVAE weights shipped for roads with ``lanes`` lanes (2 or 4), or None."""
    return shipped_weights_file(SHIPPED, lanes)


def prior_for(lanes: int, v_max: float, weights: str | Path | None, fallback: Any, gaussian_fraction: float = 0.0) -> Any:
    """The CVAE prior from ``weights`` (or the shipped weights for ``lanes``), mixing in
    ``gaussian_fraction`` of ``fallback``; ``fallback`` alone with a notice when there are no
    weights. A given but unusable file, or one trained for roads with another lane count, raises
    CheckpointError."""
    path = Path(weights) if weights else shipped_weights(lanes)
    if path is None:
        warnings.warn(f"no CVAE weights shipped for {lanes}-lane roads: using the Gaussian start instead", stacklevel=2)
        return fallback
    return load_prior(path, v_max, fallback, gaussian_fraction, lanes=lanes)


def cvae_prior(gaussian_fraction: float):
    """Prior factory of the registry's CVAE planners: ``(config, lanes, weights) -> prior`` that mixes
    ``gaussian_fraction`` of the configuration's Gaussian prior into the CVAE's first batch."""

    def make(config: PlannerConfig, lanes: int, weights: str | None) -> Any:
        gaussian = GaussianPrior.from_config(config.sampler, config.projection.v_max)
        return prior_for(lanes, config.projection.v_max, weights, gaussian, gaussian_fraction)

    return make
