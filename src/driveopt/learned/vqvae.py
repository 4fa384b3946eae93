"""VQ-VAE over expert trajectories whose decoder ends in the set-point QP (P2 §III-A, Fig. 3, eq. 5-6).

    encoder  tau_e (K, 2) -> 1-D convolutions over time -> Z_e (L, D)          (L = 10, D = 5)
    quantise z_{q,i} = e_r, r = argmin_j |z_{e,i} - e_j|^2 over the codebook E (K_c = 16 codes, eq. 5)
    decoder  (Z_q, observation o) -> bounded set-points p -> set-point QP (driveopt.qp, the planner's
             own code) -> Bernstein coefficients xi -> trajectory W xi

Loss (P2 eq. 6): mean squared distance [m^2] between W xi and tau_e at the nodes (mean over rows
and nodes of the squared x/y distance, as the CVAE's), plus the codebook term |sg[Z_e] - E|^2 and
beta |Z_e - sg[E]|^2 (beta = 0.2), both means over rows and latent vectors of the squared norm.
Quantisation passes gradients straight through (Z_e + sg[Z_q - Z_e]).

The encoder sees only the trajectory, positions relative to its start (x - x_0, y - y_0),
standardised per node with statistics of the training data; the decoder sees the codes and the
observation (:func:`driveopt.learned.cvae.observation_features`, standardised), and bounds speeds to
(0, v_max) and lateral set-points to the lane bounds of the ego centre by sigmoids. At planning
time the conditional PixelCNN (:mod:`driveopt.learned.pixelcnn`) draws the code indices.

Codebook usage: :func:`code_counts` / :func:`perplexity` (exp of the entropy of the code
frequencies: 1 when one code is used, K_c when all are used equally) and dead codes (never
assigned in an epoch), which the trainer re-seeds from encoder outputs (:func:`reseed_dead_codes`).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from pathlib import Path
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from driveopt.checks import ConfigError, check_count, check_number, check_parameters, dense_parameters
from driveopt.config import BasisConfig, ProjectionConfig, QPConfig
from driveopt.learned.checkpoint import check_scales, header_config, load_checkpoint, parameter_shapes, restore
from driveopt.learned.cvae import FEATURE_DIM, MLP, Batch, normaliser_scales, observation_features
from driveopt.qp import NUM_SEGMENTS, SETPOINT_DIM, TrajectoryModel, make_model, qp_layer

CHECKPOINT_KIND = "vqvae"


@dataclasses.dataclass(frozen=True)
class VQVAEConfig:
    num_latents: int = 10  # [-] L, latent vectors per trajectory (P2: 10)
    latent_dim: int = 5  # [-] D, size of each latent vector and code (P2: 5)
    codebook_size: int = 16  # [-] K_c, codes (P2: 16)
    beta: float = 0.2  # [-] commitment weight (P2: 0.2)
    encoder_channels: tuple[int, ...] = (32, 64)  # [-] 1-D convolution widths
    encoder_strides: tuple[int, ...] = (2, 5)  # [-] their strides: num_nodes / prod(strides) = num_latents
    kernel_size: int = 5  # [-] of the encoder convolutions
    decoder_hidden: tuple[int, ...] = (256, 256)  # [-] widths of the decoder MLP (LayerNorm, ReLU)
    v_max: float = ProjectionConfig.v_max  # [m/s] decoded speed set-points lie in (0, v_max)
    position_clip: float = 100.0  # [m] neighbour positions relative to the ego are clipped to +-this
    basis: BasisConfig = BasisConfig()
    qp: QPConfig = QPConfig()

    def __post_init__(self):
        for name in ("num_latents", "latent_dim", "kernel_size"):
            check_count(f"VQVAEConfig.{name}", getattr(self, name))
        check_count("VQVAEConfig.codebook_size", self.codebook_size, 2)
        check_number("VQVAEConfig.beta", self.beta, 0.0)
        check_number("VQVAEConfig.v_max", self.v_max, 0.0, low_open=True, unit="m/s")
        check_number("VQVAEConfig.position_clip", self.position_clip, 0.0, low_open=True, unit="m")
        if not self.encoder_channels or len(self.encoder_channels) != len(self.encoder_strides):
            raise ConfigError("VQVAEConfig.encoder_channels and encoder_strides need the same, non-zero length")
        for width in (*self.encoder_channels, *self.encoder_strides, *self.decoder_hidden):
            check_count("VQVAEConfig widths and strides", width)
        if not self.decoder_hidden:
            raise ConfigError("VQVAEConfig.decoder_hidden needs at least one width")
        if math.prod(self.encoder_strides) * self.num_latents != self.basis.num_nodes:
            raise ConfigError(f"VQVAEConfig: {self.basis.num_nodes} nodes / prod(encoder_strides) "
                              f"{math.prod(self.encoder_strides)} must equal num_latents {self.num_latents}")
        check_parameters("VQVAEConfig", self.parameter_count)

    @property
    def parameter_count(self) -> int:
        """[-] weights of the encoder's convolutions, the decoder and the codebook: what the widths cost in memory."""
        widths = (2, *self.encoder_channels)
        encoder = sum(self.kernel_size * a * b + b for a, b in itertools.pairwise(widths))
        encoder += dense_parameters([widths[-1], self.latent_dim])  # the 1 x 1 convolution to the latent vectors
        decoder = dense_parameters([self.num_latents * self.latent_dim + FEATURE_DIM, *self.decoder_hidden, SETPOINT_DIM])
        return encoder + decoder + self.codebook_size * self.latent_dim

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "VQVAEConfig":
        data = dict(data)
        basis = BasisConfig(**data.pop("basis", {}))
        qp = QPConfig.from_dict(data.pop("qp", {}))
        for name in ("encoder_channels", "encoder_strides", "decoder_hidden"):
            if name in data:
                data[name] = tuple(int(w) for w in data[name])
        return cls(**data, basis=basis, qp=qp)


class Normaliser(NamedTuple):
    """Standardisation statistics (a pytree): decoder observation features and encoder trajectories."""

    feature_mean: jnp.ndarray  # (FEATURE_DIM,)
    feature_std: jnp.ndarray
    trajectory_mean: jnp.ndarray  # (K, 2) [m] of positions relative to the start
    trajectory_std: jnp.ndarray


class Encoder(nn.Module):
    channels: tuple[int, ...]
    strides: tuple[int, ...]
    kernel_size: int
    latent_dim: int

    @nn.compact
    def __call__(self, x):  # (B, K, 2) -> (B, L, D)
        for width, stride in zip(self.channels, self.strides):
            x = nn.relu(nn.Conv(width, (self.kernel_size,), strides=(stride,), padding="SAME")(x))
        return nn.Conv(self.latent_dim, (1,))(x)


def _networks(cfg: VQVAEConfig) -> tuple[Encoder, MLP]:
    return Encoder(cfg.encoder_channels, cfg.encoder_strides, cfg.kernel_size, cfg.latent_dim), MLP(cfg.decoder_hidden, SETPOINT_DIM)


def relative_trajectory(trajectory: jnp.ndarray) -> jnp.ndarray:
    """(..., K, 2) positions relative to the first node."""
    return trajectory - trajectory[..., :1, :]


def fit_normaliser(batch: Batch, cfg: VQVAEConfig) -> Normaliser:
    """Mean and standard deviation (floored at 1e-3) of the features of ``batch``."""
    feats = np.asarray(observation_features(jnp.asarray(batch.observation), cfg.position_clip))
    trajs = np.asarray(relative_trajectory(np.asarray(batch.trajectory, np.float32)))
    stat = lambda a: (jnp.asarray(a.mean(0), jnp.float32), jnp.asarray(np.maximum(a.std(0), 1e-3), jnp.float32))  # noqa: E731
    return Normaliser(*stat(feats), *stat(trajs))


@functools.partial(jax.jit, static_argnums=0)  # one compilation per configuration, not one per operation
def init_params(cfg: VQVAEConfig, key: jax.Array) -> dict[str, Any]:
    """Encoder, decoder and codebook (K_c, D) parameters (the trainer re-seeds the codebook from encoder outputs)."""
    encoder, decoder = _networks(cfg)
    k_enc, k_dec, k_code = jax.random.split(key, 3)
    return {
        "encoder": encoder.init(k_enc, jnp.zeros((1, cfg.basis.num_nodes, 2)))["params"],
        "decoder": decoder.init(k_dec, jnp.zeros((1, cfg.num_latents * cfg.latent_dim + FEATURE_DIM)))["params"],
        "codebook": jax.random.uniform(k_code, (cfg.codebook_size, cfg.latent_dim), jnp.float32,
                                       -1.0 / cfg.codebook_size, 1.0 / cfg.codebook_size),
    }


def encode(params, cfg: VQVAEConfig, norm: Normaliser, trajectory: jnp.ndarray) -> jnp.ndarray:
    """Z_e (B, L, D) of expert trajectories (B, K, 2) [m]."""
    x = (relative_trajectory(trajectory) - norm.trajectory_mean) / norm.trajectory_std
    return _networks(cfg)[0].apply({"params": params["encoder"]}, x)


def quantise(z_e: jnp.ndarray, codebook: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """(straight-through Z_q, Z_q, indices): each latent vector (..., D) replaced by its nearest code (eq. 5).

    The straight-through value equals Z_q forward and passes the gradient to Z_e unchanged backward."""
    distances = jnp.sum((z_e[..., None, :] - codebook) ** 2, axis=-1)  # (..., K_c)
    indices = jnp.argmin(distances, axis=-1)
    z_q = codebook[indices]
    return z_e + jax.lax.stop_gradient(z_q - z_e), z_q, indices


def bounded_setpoints(raw: jnp.ndarray, lane_bounds: jnp.ndarray, v_max: float) -> jnp.ndarray:
    """(..., 8) set-points from unbounded outputs: speeds v_max * sigmoid in (0, v_max) [m/s], lateral
    positions y_lb + (y_ub - y_lb) * sigmoid within the lane bounds (..., 2) [m]."""
    share = jax.nn.sigmoid(raw)
    y_lb, y_ub = lane_bounds[..., :1], lane_bounds[..., 1:]
    return jnp.concatenate([v_max * share[..., :NUM_SEGMENTS], y_lb + (y_ub - y_lb) * share[..., NUM_SEGMENTS:]], -1)


def features(obs: jnp.ndarray, norm: Normaliser, cfg: VQVAEConfig) -> jnp.ndarray:
    """(..., FEATURE_DIM) standardised observation features (the decoder's and the PixelCNN's condition)."""
    return (observation_features(obs, cfg.position_clip) - norm.feature_mean) / norm.feature_std


def decode_setpoints(params, cfg: VQVAEConfig, norm: Normaliser, z_q: jnp.ndarray, obs: jnp.ndarray, lane_bounds: jnp.ndarray):
    """(B, 8) set-points from quantised latents (B, L, D) and observations (B, 55)."""
    flat = z_q.reshape(*z_q.shape[:-2], -1)
    raw = _networks(cfg)[1].apply({"params": params["decoder"]}, jnp.concatenate([flat, features(obs, norm, cfg)], -1))
    return bounded_setpoints(raw, lane_bounds, cfg.v_max)


def decode_codes(params, cfg: VQVAEConfig, norm: Normaliser, codes: jnp.ndarray, obs: jnp.ndarray, lane_bounds: jnp.ndarray):
    """(B, 8) set-points from code indices (B, L) (what the PixelCNN samples)."""
    return decode_setpoints(params, cfg, norm, params["codebook"][codes], obs, lane_bounds)


def trajectory_model(cfg: VQVAEConfig) -> TrajectoryModel:
    return make_model(cfg.basis, cfg.qp)


def example_terms(params, cfg: VQVAEConfig, norm: Normaliser, batch: Batch) -> dict[str, jnp.ndarray]:
    """Per row: reconstruction [m^2] (mean over nodes), codebook and commitment distances (means over the
    L latent vectors of the squared norm), each (B,); and the code indices (B, L)."""
    z_e = encode(params, cfg, norm, batch.trajectory)
    z_st, _, indices = quantise(z_e, params["codebook"])
    setpoints = decode_setpoints(params, cfg, norm, z_st, batch.observation, batch.lane_bounds)
    _, positions = qp_layer(trajectory_model(cfg), cfg.qp, setpoints, batch.init_x, batch.init_y)
    z_q = params["codebook"][indices]  # gradients reach the codebook through this lookup only
    return {
        "reconstruction": jnp.mean(jnp.sum((positions - batch.trajectory) ** 2, axis=-1), axis=-1),
        "codebook": jnp.mean(jnp.sum((jax.lax.stop_gradient(z_e) - z_q) ** 2, axis=-1), axis=-1),
        "commitment": jnp.mean(jnp.sum((z_e - jax.lax.stop_gradient(z_q)) ** 2, axis=-1), axis=-1),
        "indices": indices,
    }


def code_counts(indices: jnp.ndarray, codebook_size: int) -> jnp.ndarray:
    """(K_c,) how often each code was assigned among ``indices`` (any shape)."""
    return jnp.bincount(jnp.ravel(indices), length=codebook_size)


def perplexity(counts: Any) -> float:
    """exp(entropy) of the code frequencies: the effective number of codes in use (1 to K_c)."""
    counts = np.asarray(counts, np.float64)
    total = counts.sum()
    if total <= 0:
        return 0.0
    p = counts[counts > 0] / total
    return float(np.exp(-np.sum(p * np.log(p))))


def loss(params, cfg: VQVAEConfig, norm: Normaliser, batch: Batch):
    """P2 eq. 6: reconstruction + codebook + beta * commitment; returns (loss, terms with "counts" (K_c,))."""
    terms = example_terms(params, cfg, norm, batch)
    means = {k: jnp.mean(terms[k]) for k in ("reconstruction", "codebook", "commitment")}
    value = means["reconstruction"] + means["codebook"] + cfg.beta * means["commitment"]
    return value, {**means, "counts": code_counts(terms["indices"], cfg.codebook_size)}


def reseed_dead_codes(codebook: jnp.ndarray, counts: jnp.ndarray, candidates: jnp.ndarray, key: jax.Array) -> jnp.ndarray:
    """``codebook`` (K_c, D) with every dead code (``counts`` 0) replaced by a distinct encoder output drawn at
    random from ``candidates`` (N, D) (with replacement only when there are fewer than K_c); live codes are kept."""
    dead = jnp.asarray(counts) == 0
    n = candidates.shape[0]
    picks = jax.random.choice(key, n, (codebook.shape[0],), replace=n < codebook.shape[0])
    return jnp.where(dead[:, None], candidates[picks], codebook)


def empty_state(cfg: VQVAEConfig) -> dict[str, Any]:
    """The structure of a VQ-VAE checkpoint's state (parameters and normaliser; shapes only), for restoring."""
    zeros = lambda *shape: jax.ShapeDtypeStruct(shape, jnp.float32)  # noqa: E731
    nodes = cfg.basis.num_nodes
    return {"params": parameter_shapes(init_params, cfg),
            "normaliser": Normaliser(zeros(FEATURE_DIM), zeros(FEATURE_DIM), zeros(nodes, 2), zeros(nodes, 2))}


def load_vqvae(path: str | Path, lanes: int | None = None) -> tuple[VQVAEConfig, Any, Normaliser, dict[str, Any]]:
    """(config, params, normaliser, meta) of a VQ-VAE checkpoint; CheckpointError when unusable, or when ``lanes``
    is given and the checkpoint was trained for roads with other lane counts."""
    meta, state = load_checkpoint(path, CHECKPOINT_KIND, lanes)
    cfg = header_config(meta, path, VQVAEConfig, "VQ-VAE")
    restored = restore(empty_state(cfg), {k: state.get(k) for k in ("params", "normaliser")}, path, "the VQ-VAE state")
    norm = Normaliser(*restored["normaliser"])
    check_scales(path, "the VQ-VAE state", normaliser_scales(norm))
    return cfg, restored["params"], norm, meta
