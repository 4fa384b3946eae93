"""Conditional VAE over behavioural set-points whose decoder ends in the set-point QP (P1 §III-D, App. I).

    encoder (observation o, expert trajectory tau_e) -> (mu_z, log sigma_z^2)
    decoder (z, o) -> bounded set-points p -> set-point QP (driveopt.qp, the planner's own code)
                   -> Bernstein coefficients xi -> trajectory W xi

Loss (P1 eq. 9): mean squared distance [m^2] between W xi and tau_e at the nodes, plus
beta * KL(q(z | o, tau_e) || N(0, I)); beta is annealed from 0 by the trainer. At planning time
z ~ N(0, I) gives the first batch of set-points (:class:`driveopt.priors.cvae.CVAEPrior`).

Inputs are standardised with statistics of the training data (:class:`Normaliser`, saved with the
weights). Neighbour positions are clipped to ``position_clip`` first and a presence flag is added
per neighbour, so the far-away padding of the observation does not dominate the statistics.
Speed set-points are bounded to (0, v_max) and lateral set-points to the lane bounds of the
ego centre (y_lb, y_ub) by sigmoids.

Widths: P1 uses 4 x 1024 + 256 with BatchNorm. The default here is 3 x 256 with LayerNorm: it
trains on the 2-core CPU in minutes, adds about a millisecond per planning call for 1000
samples, and LayerNorm has no running statistics, so training and planning (one observation,
any batch size) compute the same function.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from driveopt.checks import ConfigError, check_count, check_number, check_parameters, dense_parameters
from driveopt.config import BasisConfig, ProjectionConfig, QPConfig
from driveopt.learned.checkpoint import check_scales, header_config, load_checkpoint, parameter_shapes, restore
from driveopt.observation import EGO_FEATURES, NEIGHBOUR_FEATURES, NUM_NEIGHBOURS, OBSERVATION_DIM, neighbour_mask
from driveopt.qp import NUM_SEGMENTS, SETPOINT_DIM, TrajectoryModel, make_model, qp_layer

CHECKPOINT_KIND = "cvae"
FEATURE_DIM = OBSERVATION_DIM + NUM_NEIGHBOURS  # observation + a presence flag per neighbour


@dataclasses.dataclass(frozen=True)
class CVAEConfig:
    latent_dim: int = 2  # [-] P1: 2
    hidden: tuple[int, ...] = (256, 256, 256)  # [-] widths of the encoder and decoder MLPs
    v_max: float = ProjectionConfig.v_max  # [m/s] decoded speed set-points lie in (0, v_max)
    position_clip: float = 100.0  # [m] neighbour positions relative to the ego are clipped to +-this
    trajectory_stride: int = 4  # [-] every stride-th node of tau_e feeds the encoder
    basis: BasisConfig = BasisConfig()
    qp: QPConfig = QPConfig()

    def __post_init__(self):
        check_count("CVAEConfig.latent_dim", self.latent_dim)
        if not self.hidden:
            raise ConfigError("CVAEConfig.hidden needs at least one width")
        for width in self.hidden:
            check_count("CVAEConfig.hidden widths", width)
        check_number("CVAEConfig.v_max", self.v_max, 0.0, low_open=True, unit="m/s")
        check_number("CVAEConfig.position_clip", self.position_clip, 0.0, low_open=True, unit="m")
        check_count("CVAEConfig.trajectory_stride", self.trajectory_stride)
        check_parameters("CVAEConfig", self.parameter_count)

    @property
    def parameter_count(self) -> int:
        """[-] weights of the encoder and the decoder (LayerNorm scales aside): what the widths cost in memory."""
        encoder = dense_parameters([FEATURE_DIM + self.trajectory_features, *self.hidden, 2 * self.latent_dim])
        return encoder + dense_parameters([self.latent_dim + FEATURE_DIM, *self.hidden, SETPOINT_DIM])

    @property
    def trajectory_features(self) -> int:
        return 2 * len(range(0, self.basis.num_nodes, self.trajectory_stride))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "CVAEConfig":
        data = dict(data)
        basis = BasisConfig(**data.pop("basis", {}))
        qp = QPConfig.from_dict(data.pop("qp", {}))
        if "hidden" in data:
            data["hidden"] = tuple(int(w) for w in data["hidden"])
        return cls(**data, basis=basis, qp=qp)


class Normaliser(NamedTuple):
    """Standardisation statistics of the encoder and decoder inputs (a pytree)."""

    feature_mean: jnp.ndarray  # (FEATURE_DIM,)
    feature_std: jnp.ndarray
    trajectory_mean: jnp.ndarray  # (cfg.trajectory_features,)
    trajectory_std: jnp.ndarray


class Batch(NamedTuple):
    """Training rows (B leading): everything the loss needs."""

    observation: jnp.ndarray  # (B, 55)
    trajectory: jnp.ndarray  # (B, K, 2) [m] expert plan, x relative to the ego
    init_x: jnp.ndarray  # (B, 3)
    init_y: jnp.ndarray  # (B, 3)
    lane_bounds: jnp.ndarray  # (B, 2) [m] (y_lb, y_ub)


class MLP(nn.Module):
    """Hidden layers with LayerNorm and ReLU, then a linear output layer (``zero_output``: initialised at zero)."""

    hidden: tuple[int, ...]
    out: int
    zero_output: bool = False

    @nn.compact
    def __call__(self, x):
        for width in self.hidden:
            x = nn.relu(nn.LayerNorm()(nn.Dense(width)(x)))
        if self.zero_output:
            return nn.Dense(self.out, kernel_init=nn.initializers.zeros, bias_init=nn.initializers.zeros)(x)
        return nn.Dense(self.out)(x)


def observation_features(obs: jnp.ndarray, position_clip: float) -> jnp.ndarray:
    """(..., 55) observation -> (..., 65): neighbour positions clipped, presence flags appended."""
    ego = obs[..., :EGO_FEATURES]
    nb = obs[..., EGO_FEATURES:].reshape(*obs.shape[:-1], NUM_NEIGHBOURS, NEIGHBOUR_FEATURES)
    present = neighbour_mask(obs).astype(obs.dtype)
    nb = jnp.concatenate([jnp.clip(nb[..., :2], -position_clip, position_clip), nb[..., 2:]], axis=-1)
    return jnp.concatenate([ego, nb.reshape(*obs.shape[:-1], -1), present], axis=-1)


def trajectory_features(trajectory: jnp.ndarray, stride: int) -> jnp.ndarray:
    """(..., K, 2) -> (..., 2 * ceil(K / stride)): x, and y relative to the start, at every stride-th node."""
    sub = trajectory[..., ::stride, :]
    rel = jnp.stack([sub[..., 0], sub[..., 1] - trajectory[..., :1, 1]], axis=-1)
    return rel.reshape(*trajectory.shape[:-2], -1)


def fit_normaliser(batch: Batch, cfg: CVAEConfig) -> Normaliser:
    """Mean and standard deviation (floored at 1e-3) of the features of ``batch``."""
    feats = np.asarray(observation_features(jnp.asarray(batch.observation), cfg.position_clip))
    trajs = np.asarray(trajectory_features(jnp.asarray(batch.trajectory), cfg.trajectory_stride))
    stat = lambda a: (jnp.asarray(a.mean(0), jnp.float32), jnp.asarray(np.maximum(a.std(0), 1e-3), jnp.float32))  # noqa: E731
    return Normaliser(*stat(feats), *stat(trajs))


def _networks(cfg: CVAEConfig) -> tuple[MLP, MLP]:
    return MLP(cfg.hidden, 2 * cfg.latent_dim), MLP(cfg.hidden, SETPOINT_DIM)


def init_params(cfg: CVAEConfig, key: jax.Array) -> dict[str, Any]:
    encoder, decoder = _networks(cfg)
    k_enc, k_dec = jax.random.split(key)
    return {
        "encoder": encoder.init(k_enc, jnp.zeros((1, FEATURE_DIM + cfg.trajectory_features)))["params"],
        "decoder": decoder.init(k_dec, jnp.zeros((1, cfg.latent_dim + FEATURE_DIM)))["params"],
    }


def _features(obs: jnp.ndarray, norm: Normaliser, cfg: CVAEConfig) -> jnp.ndarray:
    return (observation_features(obs, cfg.position_clip) - norm.feature_mean) / norm.feature_std


def encode(params, cfg: CVAEConfig, norm: Normaliser, obs: jnp.ndarray, trajectory: jnp.ndarray):
    """(mu, log variance), each (B, latent_dim), of q(z | o, tau_e)."""
    traj = (trajectory_features(trajectory, cfg.trajectory_stride) - norm.trajectory_mean) / norm.trajectory_std
    out = _networks(cfg)[0].apply({"params": params["encoder"]}, jnp.concatenate([_features(obs, norm, cfg), traj], -1))
    mu, log_var = jnp.split(out, 2, axis=-1)
    return mu, jnp.clip(log_var, -10.0, 5.0)


def decode_setpoints(params, cfg: CVAEConfig, norm: Normaliser, z: jnp.ndarray, obs: jnp.ndarray, lane_bounds: jnp.ndarray):
    """(B, 8) set-points: speeds in (0, v_max) [m/s], lateral positions in (y_lb, y_ub) [m]."""
    raw = _networks(cfg)[1].apply({"params": params["decoder"]}, jnp.concatenate([z, _features(obs, norm, cfg)], -1))
    share = jax.nn.sigmoid(raw)
    y_lb, y_ub = lane_bounds[..., :1], lane_bounds[..., 1:]
    return jnp.concatenate([cfg.v_max * share[..., :NUM_SEGMENTS], y_lb + (y_ub - y_lb) * share[..., NUM_SEGMENTS:]], -1)


def trajectory_model(cfg: CVAEConfig) -> TrajectoryModel:
    return make_model(cfg.basis, cfg.qp)


def loss_terms(params, cfg: CVAEConfig, norm: Normaliser, batch: Batch, key: jax.Array) -> dict[str, jnp.ndarray]:
    """Reconstruction [m^2] (mean over rows and nodes) and KL [nats] (mean over rows), reparameterised."""
    mu, log_var = encode(params, cfg, norm, batch.observation, batch.trajectory)
    z = mu + jnp.exp(0.5 * log_var) * jax.random.normal(key, mu.shape, mu.dtype)
    setpoints = decode_setpoints(params, cfg, norm, z, batch.observation, batch.lane_bounds)
    _, positions = qp_layer(trajectory_model(cfg), cfg.qp, setpoints, batch.init_x, batch.init_y)
    reconstruction = jnp.mean(jnp.sum((positions - batch.trajectory) ** 2, axis=-1))
    kl = jnp.mean(0.5 * jnp.sum(mu**2 + jnp.exp(log_var) - 1.0 - log_var, axis=-1))
    return {"reconstruction": reconstruction, "kl": kl}


def loss(params, cfg: CVAEConfig, norm: Normaliser, batch: Batch, key: jax.Array, beta: jnp.ndarray):
    """P1 eq. 9: reconstruction + beta * KL; returns (loss, terms)."""
    terms = loss_terms(params, cfg, norm, batch, key)
    return terms["reconstruction"] + beta * terms["kl"], terms


def prior_coverage(params, cfg: CVAEConfig, norm: Normaliser, batch: Batch, key: jax.Array, num: int = 16) -> jnp.ndarray:
    """(B,) [m^2] for each row, the smallest mean squared node distance to the expert trajectory among
    ``num`` trajectories decoded from z ~ N(0, I): how well planning-time samples cover the expert."""
    model = trajectory_model(cfg)

    def row(obs, lanes, init_x, init_y, target, k):
        setpoints = sample_setpoints(params, cfg, norm, obs, lanes, k, num)
        _, positions = qp_layer(model, cfg.qp, setpoints, jnp.broadcast_to(init_x, (num, 3)), jnp.broadcast_to(init_y, (num, 3)))
        return jnp.min(jnp.mean(jnp.sum((positions - target) ** 2, -1), -1))

    keys = jax.random.split(key, batch.observation.shape[0])
    return jax.vmap(row)(batch.observation, batch.lane_bounds, batch.init_x, batch.init_y, batch.trajectory, keys)


def sample_setpoints(params, cfg: CVAEConfig, norm: Normaliser, obs: jnp.ndarray, lane_bounds: jnp.ndarray, key: jax.Array, num: int):
    """(num, 8) set-points for one observation (55,) from z ~ N(0, I)."""
    z = jax.random.normal(key, (num, cfg.latent_dim))
    obs = jnp.broadcast_to(obs, (num, obs.shape[-1]))
    return decode_setpoints(params, cfg, norm, z, obs, jnp.broadcast_to(lane_bounds, (num, 2)))


def empty_state(cfg: CVAEConfig) -> dict[str, Any]:
    """The structure of a CVAE checkpoint's state (parameters and normaliser; shapes only, traced, not computed), for restoring."""
    zeros = lambda n: jax.ShapeDtypeStruct((n,), jnp.float32)  # noqa: E731
    return {"params": parameter_shapes(init_params, cfg),
            "normaliser": Normaliser(zeros(FEATURE_DIM), zeros(FEATURE_DIM), zeros(cfg.trajectory_features),
                                     zeros(cfg.trajectory_features))}


def load_cvae(path: str | Path, lanes: int | None = None) -> tuple[CVAEConfig, Any, Normaliser, dict[str, Any]]:
    """(config, params, normaliser, meta) of a CVAE checkpoint; CheckpointError when unusable, or when
    ``lanes`` is given and the checkpoint was trained for roads with other lane counts (:func:`check_lanes`)."""
    meta, state = load_checkpoint(path, CHECKPOINT_KIND, lanes)
    cfg = header_config(meta, path, CVAEConfig, "CVAE")
    target = empty_state(cfg)
    restored = restore(target, {k: state.get(k) for k in target}, path, "the CVAE state")
    norm = Normaliser(*restored["normaliser"])
    check_scales(path, "the CVAE state", normaliser_scales(norm))
    return cfg, restored["params"], norm, meta


def normaliser_scales(norm: Any) -> dict[str, Any]:
    """name -> standard deviations of a normaliser (the CVAE's or the VQ-VAE's: same fields), for check_scales."""
    return {f"normaliser.{name}": getattr(norm, name) for name in norm._fields if name.endswith("_std")}
