"""The VQ-VAE prior: set-points sampled from the PixelCNN and decoded by the VQ-VAE (P2 §III, Fig. 2); shipped weights.

``VQVAEPrior.propose`` draws ``num`` code sequences from the conditional PixelCNN for the problem's
observation (one jitted ``fori_loop``), looks them up in the codebook, decodes set-points (speeds in
(0, v_max), lateral positions within the lane bounds) and returns them with their mean and
covariance. The registry's ``vqvae`` planner is P2's pipeline: these samples -> set-point QP ->
projection (barrier form, 100 iterations) as safety filter -> the least-cost feasible sample, in one
pass; ``vqvae-cem`` uses them as the first batch of the bi-level optimiser. ``warm_mean`` is not used.

Weights are one PixelCNN checkpoint (``driveopt train pixelcnn``), which embeds its VQ-VAE; it records
the lane counts of its training roads, and :func:`prior_for` refuses weights trained for another
lane count. Without weights for a road (two- and four-lane ones ship) the planners warn and use the Gaussian start.

Flax is imported when weights are loaded or sampled, not with this module.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import jax.numpy as jnp

from driveopt.config import PlannerConfig, ProjectionConfig
from driveopt.files import shipped_weights_file
from driveopt.pytree import pytree_dataclass, static
from driveopt.sampler import GaussianPrior, Proposal, clip_setpoints, moments

COVARIANCE_JITTER = 0.01  # [-] added to the diagonal of the proposal's covariance
SHIPPED = {2: "vqvae-two-lane.ckpt", 4: "vqvae-four-lane.ckpt"}  # lanes -> file in driveopt/weights


@pytree_dataclass
class VQVAEPrior:
    """First proposal from the PixelCNN + VQ-VAE decoder (a :mod:`~driveopt.pytree` dataclass)."""

    vqvae_params: Any
    normaliser: Any  # driveopt.learned.vqvae.Normaliser
    pixelcnn_params: Any
    vqvae_config: Any = static()  # driveopt.learned.vqvae.VQVAEConfig
    pixelcnn_config: Any = static()  # driveopt.learned.pixelcnn.PixelCNNConfig
    v_max: float = static(ProjectionConfig.v_max)  # [m/s] planner's bound

    def sample_setpoints(self, problem, key, num) -> jnp.ndarray:
        """(num, 8) decoded set-points for the problem's observation (not clipped to the planner's bounds)."""
        from driveopt.learned.pixelcnn import sample_codes
        from driveopt.learned.vqvae import decode_codes, features

        feats = features(problem.observation, self.normaliser, self.vqvae_config)
        codes = sample_codes(self.pixelcnn_params, self.pixelcnn_config, feats, key, num)
        obs = jnp.broadcast_to(problem.observation, (num, problem.observation.shape[-1]))
        lanes = jnp.broadcast_to(jnp.stack([problem.y_lb, problem.y_ub]), (num, 2))
        return decode_codes(self.vqvae_params, self.vqvae_config, self.normaliser, codes, obs, lanes)

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        samples = clip_setpoints(self.sample_setpoints(problem, key, num), problem, self.v_max)
        return Proposal(samples, *moments(samples, COVARIANCE_JITTER))


def load_prior(path: str | Path, v_max: float = ProjectionConfig.v_max, lanes: int | None = None) -> VQVAEPrior:
    """The prior of the PixelCNN checkpoint ``path``; with ``lanes``, CheckpointError when it records that it was
    trained for roads with other lane counts."""
    from driveopt.learned.pixelcnn import load_vqvae_prior

    loaded = load_vqvae_prior(path, lanes)
    return VQVAEPrior(loaded["vqvae_params"], loaded["normaliser"], loaded["params"], loaded["vqvae_config"],
                      loaded["config"], float(v_max))


def shipped_weights(lanes: int) -> Path | None:
    """Path of the VQ-VAE prior weights shipped for roads with ``lanes`` lanes, or None."""
    return shipped_weights_file(SHIPPED, lanes)


def prior_for(lanes: int, v_max: float, weights: str | Path | None, fallback: Any) -> Any:
    """The VQ-VAE prior from ``weights`` (or the shipped weights for ``lanes``); ``fallback`` with a notice when there
    are none. A given but unusable file, or one trained for another lane count, raises CheckpointError."""
    path = Path(weights) if weights else shipped_weights(lanes)
    if path is None:
        warnings.warn(f"no VQ-VAE weights shipped for {lanes}-lane roads: using the Gaussian start instead", stacklevel=2)
        return fallback
    return load_prior(path, v_max, lanes=lanes)


def vqvae_prior():
    """Prior factory of the registry's VQ-VAE planners: ``(config, lanes, weights) -> prior``, falling back to the
    configuration's Gaussian prior."""

    def make(config: PlannerConfig, lanes: int, weights: str | None) -> Any:
        gaussian = GaussianPrior.from_config(config.sampler, config.projection.v_max)
        return prior_for(lanes, config.projection.v_max, weights, gaussian)

    return make
