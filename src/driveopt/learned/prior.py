"""The CVAE as the bi-level sampler's first proposal (P1 §III-D), and the weights shipped with driveopt.

``CVAEPrior.propose`` draws z ~ N(0, I), decodes set-points for the problem's observation, and
initialises the sampler's Gaussian with their mean and covariance; later iterations adapt it as
for any prior. The CVAE replaces the warm start (``warm_mean`` is not used).
"""

from __future__ import annotations

import dataclasses
import warnings
from importlib import resources
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from driveopt.learned.checkpoint import CheckpointError, load_checkpoint, restore
from driveopt.learned.cvae import FEATURE_DIM, CVAEConfig, Normaliser, init_params, sample_setpoints
from driveopt.sampler import Proposal, clip_setpoints

KIND = "cvae"
COVARIANCE_JITTER = 0.01  # [-] added to the diagonal of the proposal's covariance


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CVAEPrior:
    """First proposal from the CVAE; with ``gaussian_fraction`` > 0 that share of the batch comes from
    ``gaussian`` instead (a prior of :mod:`driveopt.sampler`, centred on the warm start).

    P1 draws the whole batch from the CVAE (``gaussian_fraction = 0``). Its samples stay around the
    expert's choice (mostly one lane, about 3 m/s of spread in speed), so where that choice is
    blocked hardly any sample projects to a feasible plan, the optimiser keeps the stopping plans and
    can stay stopped; the Gaussian share keeps the behaviours around the current motion in every batch.
    """

    params: Any
    normaliser: Normaliser
    config: CVAEConfig = dataclasses.field(metadata=dict(static=True))
    v_max: float = dataclasses.field(default=30.0, metadata=dict(static=True))  # [m/s] planner's speed bound
    gaussian: Any = None
    gaussian_fraction: float = dataclasses.field(default=0.0, metadata=dict(static=True))  # [-]

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        k_cvae, k_gauss = jax.random.split(key)
        mixed = int(round(self.gaussian_fraction * num)) if self.gaussian is not None else 0
        lane_bounds = jnp.stack([problem.y_lb, problem.y_ub])
        samples = sample_setpoints(self.params, self.config, self.normaliser, problem.observation, lane_bounds, k_cvae, num - mixed)
        if mixed:
            samples = jnp.concatenate([samples, self.gaussian.propose(problem, k_gauss, mixed, warm_mean).samples])
        samples = clip_setpoints(samples, problem, self.v_max)
        mean = jnp.mean(samples, axis=0)
        centred = samples - mean
        cov = centred.T @ centred / num + COVARIANCE_JITTER * jnp.eye(samples.shape[1], dtype=samples.dtype)
        return Proposal(samples, mean, cov)


def empty_state(cfg: CVAEConfig) -> dict[str, Any]:
    """The structure of a CVAE checkpoint's state (parameters and normaliser), for restoring."""
    zeros = lambda n: jnp.zeros(n, jnp.float32)  # noqa: E731
    return {"params": init_params(cfg, jax.random.PRNGKey(0)),
            "normaliser": Normaliser(zeros(FEATURE_DIM), zeros(FEATURE_DIM), zeros(cfg.trajectory_features), zeros(cfg.trajectory_features))}


def load_cvae(path: str | Path) -> tuple[CVAEConfig, Any, Normaliser, dict[str, Any]]:
    """(config, params, normaliser, meta) of a CVAE checkpoint; CheckpointError when unusable."""
    meta, state = load_checkpoint(path, KIND)
    try:
        cfg = CVAEConfig.from_dict(meta["config"])
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{path}: invalid CVAE config in the header: {exc}") from None
    target = empty_state(cfg)
    restored = restore(target, {k: state.get(k) for k in target}, path, "the CVAE state")
    return cfg, restored["params"], Normaliser(*restored["normaliser"]), meta


def load_prior(path: str | Path, v_max: float = 30.0, gaussian: Any = None, gaussian_fraction: float = 0.0) -> CVAEPrior:
    cfg, params, norm, _ = load_cvae(path)
    return CVAEPrior(params, norm, cfg, float(v_max), gaussian, float(gaussian_fraction))


def shipped_weights(lanes: int) -> Path | None:
    """Path of the CVAE weights shipped for roads with ``lanes`` lanes (2 or 4), or None."""
    name = {2: "cvae-two-lane.ckpt", 4: "cvae-four-lane.ckpt"}.get(int(lanes))
    if name is None:
        return None
    path = Path(str(resources.files("driveopt") / "weights" / name))
    return path if path.exists() else None


def prior_for(lanes: int, v_max: float, weights: str | Path | None, fallback: Any, gaussian_fraction: float = 0.0) -> Any:
    """The CVAE prior from ``weights`` (or the shipped weights for ``lanes``), mixing in
    ``gaussian_fraction`` of ``fallback``; ``fallback`` alone with a notice when there are no
    weights. A given but unusable file raises CheckpointError."""
    path = Path(weights) if weights else shipped_weights(lanes)
    if path is None:
        warnings.warn(f"no CVAE weights shipped for {lanes}-lane roads: using the Gaussian start instead", stacklevel=2)
        return fallback
    return load_prior(path, v_max, fallback, gaussian_fraction)
