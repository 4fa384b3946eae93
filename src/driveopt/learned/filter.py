"""P2's learned safety filter network (§III-C, Fig. 5): (observation, sampled trajectory) -> how its projection starts.

Input, per sample (77 = 55 + 22, as in the authors' code): the 55-dim observation
(:mod:`driveopt.observation`; neighbour positions clipped to +-``position_clip``, so the far-away
padding does not dominate) and the sample's Bernstein coefficients xi (x in the planning frame, y
relative to the ego's current y), standardised with statistics of the training data
(:class:`Normaliser`, saved with the weights). An MLP (``hidden``: four layers, as the authors'; LayerNorm
and ReLU as the CVAE's, so one sample computes what a batch computes) maps it to 2 + 4n outputs r
(46 for the order-10 basis), read as (:func:`initialise`)::

    gamma_obs, gamma_lane = gamma_min + (1 - gamma_min) * sigmoid(r_0), ... (r_1)    in (gamma_min, 1) [-]
    lambda_0 = multiplier_scale * r[2 : 2 + 2n]                                       initial multipliers [m]
    xi_bar_0 = xi + coeff_scale * r[2 + 2n :]                                         first iterate [m]

which :func:`driveopt.projection.project` uses as the per-sample barrier parameters, initial
multipliers and first iterate (the multipliers enter the linear step as ``target + lambda + rho F'h``,
in coefficient units, metres). The output layer starts with zero weights and its gamma biases at
``gamma_obs_init`` / ``gamma_lane_init``: the untrained filter is the barrier projection with those
gammas, started from the sample with zero multipliers, and training moves away from it.

The pytree the planner takes is :class:`driveopt.safety.learned.LearnedFilter`; training is
:mod:`driveopt.training.filter`.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from driveopt.checks import ConfigError, check_count, check_number, check_parameters, dense_parameters
from driveopt.config import BasisConfig
from driveopt.filtering import FilterError, FilterInit
from driveopt.learned.checkpoint import check_scales, header_config, load_checkpoint, parameter_shapes, restore
from driveopt.observation import EGO_FEATURES, NEIGHBOUR_FEATURES, OBSERVATION_DIM
from driveopt.problem import PlanningProblem

CHECKPOINT_KIND = "safety-filter"
GAMMA_OUTPUTS = 2  # gamma_obs, gamma_lane
OUTPUT_LAYER = "output"  # name of the last Dense layer in the parameters


@dataclasses.dataclass(frozen=True)
class FilterConfig:
    hidden: tuple[int, ...] = (256, 256, 256, 256)  # [-] MLP widths (the authors': four hidden layers)
    gamma_min: float = 0.5  # [-] in (0, 1): predicted gammas lie in (gamma_min, 1); small ones converge slowly
    gamma_obs_init: float = 0.98  # [-] gamma_obs of the untrained network (P2 trains with 0.98)
    gamma_lane_init: float = 0.9  # [-] gamma_lane of the untrained network (P2: 0.9)
    coeff_scale: float = 1.0  # [m] first iterate = xi + coeff_scale * output
    multiplier_scale: float = 1.0  # [m] initial multipliers = multiplier_scale * output
    position_clip: float = 100.0  # [m] neighbour positions relative to the ego are clipped to +-this
    basis: BasisConfig = BasisConfig()  # the planner's basis (the number of coefficients)

    def __post_init__(self):
        if not self.hidden:
            raise ConfigError("FilterConfig.hidden needs at least one width")
        for width in self.hidden:
            check_count("FilterConfig.hidden widths", width)
        check_number("FilterConfig.gamma_min", self.gamma_min, 0.0, 1.0, low_open=True, high_open=True)
        for name in ("gamma_obs_init", "gamma_lane_init"):
            check_number(f"FilterConfig.{name}", getattr(self, name), self.gamma_min, 1.0, low_open=True, high_open=True)
        check_number("FilterConfig.coeff_scale", self.coeff_scale, 0.0, low_open=True, unit="m")
        check_number("FilterConfig.multiplier_scale", self.multiplier_scale, 0.0, low_open=True, unit="m")
        check_number("FilterConfig.position_clip", self.position_clip, 0.0, low_open=True, unit="m")
        check_parameters("FilterConfig", self.parameter_count)

    @property
    def parameter_count(self) -> int:
        """[-] weights of the MLP (LayerNorm scales aside): what the widths cost in memory."""
        return dense_parameters([self.input_dim, *self.hidden, self.output_dim])

    @property
    def num_coeffs(self) -> int:
        """2n: coefficients of one trajectory (both axes)."""
        return 2 * self.basis.num_coeffs

    @property
    def input_dim(self) -> int:
        return OBSERVATION_DIM + self.num_coeffs

    @property
    def output_dim(self) -> int:
        return GAMMA_OUTPUTS + 2 * self.num_coeffs

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "FilterConfig":
        data = dict(data)
        basis = BasisConfig(**data.pop("basis", {}))
        if "hidden" in data:
            data["hidden"] = tuple(int(w) for w in data["hidden"])
        return cls(**data, basis=basis)


class Normaliser(NamedTuple):
    """Standardisation of the network's input (a pytree)."""

    mean: jnp.ndarray  # (input_dim,)
    std: jnp.ndarray  # (input_dim,)


def _logit(share: float) -> float:
    return math.log(share / (1.0 - share))


class FilterMLP(nn.Module):
    """Hidden layers with LayerNorm and ReLU, then a zero-weight output layer whose bias is ``output_bias``."""

    hidden: tuple[int, ...]
    output_bias: tuple[float, ...]

    @nn.compact
    def __call__(self, x):
        for width in self.hidden:
            x = nn.relu(nn.LayerNorm()(nn.Dense(width)(x)))
        bias = jnp.asarray(self.output_bias, jnp.float32)
        return nn.Dense(len(self.output_bias), kernel_init=nn.initializers.zeros,
                        bias_init=lambda key, shape, dtype=jnp.float32: bias.astype(dtype), name=OUTPUT_LAYER)(x)


def _network(cfg: FilterConfig) -> FilterMLP:
    share = lambda gamma: (gamma - cfg.gamma_min) / (1.0 - cfg.gamma_min)  # noqa: E731
    bias = (_logit(share(cfg.gamma_obs_init)), _logit(share(cfg.gamma_lane_init))) + (0.0,) * (2 * cfg.num_coeffs)
    return FilterMLP(cfg.hidden, bias)


def init_params(cfg: FilterConfig, key: jax.Array) -> dict[str, Any]:
    return _network(cfg).init(key, jnp.zeros((1, cfg.input_dim), jnp.float32))["params"]


SATURATED = 30.0  # [-] an output-layer bias whose sigmoid is 1 in float32


def plain_params(params, cfg: FilterConfig, gamma_obs: float = 1.0, gamma_lane: float = 1.0) -> dict[str, Any]:
    """``params`` with the output layer replaced so that the filter is the plain projection: the given gammas (1:
    exactly 1), the samples themselves as first iterate, zero multipliers (hidden layers kept, they no longer matter)."""
    def bias(gamma: float) -> float:
        share = (gamma - cfg.gamma_min) / (1.0 - cfg.gamma_min)
        return SATURATED if share >= 1.0 else _logit(min(max(share, 1e-6), 1.0 - 1e-6))

    out = params[OUTPUT_LAYER]
    b = jnp.zeros_like(out["bias"]).at[0].set(bias(gamma_obs)).at[1].set(bias(gamma_lane))
    return {**params, OUTPUT_LAYER: {"kernel": jnp.zeros_like(out["kernel"]), "bias": b}}


def raw_features(observation: jnp.ndarray, ego_y: jnp.ndarray, coeffs: jnp.ndarray, cfg: FilterConfig) -> jnp.ndarray:
    """(B, 77) unstandardised input: the observation (55,) with clipped neighbour positions, repeated per sample,
    and each sample's coefficients (B, 2n), y relative to ``ego_y`` [m]."""
    ego = observation[..., :EGO_FEATURES]
    rows = observation[..., EGO_FEATURES:].reshape(*observation.shape[:-1], -1, NEIGHBOUR_FEATURES)
    rows = jnp.concatenate([jnp.clip(rows[..., :2], -cfg.position_clip, cfg.position_clip), rows[..., 2:]], axis=-1)
    obs = jnp.concatenate([ego, rows.reshape(*observation.shape[:-1], -1)], axis=-1)
    n = cfg.basis.num_coeffs
    relative = jnp.concatenate([coeffs[..., :n], coeffs[..., n:] - ego_y[..., None]], axis=-1)
    return jnp.concatenate([jnp.broadcast_to(obs, (*relative.shape[:-1], obs.shape[-1])), relative], axis=-1)


def fit_normaliser(observation: np.ndarray, ego_y: np.ndarray, coeffs: np.ndarray, cfg: FilterConfig) -> Normaliser:
    """Mean and standard deviation (floored at 1e-3) of the input for rows of observations (R, 55), ego lateral
    positions (R,) [m] and trajectories (R, 2n) [m] (the demonstrations' plans stand for the samples)."""
    feats = np.asarray(raw_features(jnp.asarray(observation, jnp.float32), jnp.asarray(ego_y, jnp.float32),
                                    jnp.asarray(coeffs, jnp.float32), cfg))
    return Normaliser(jnp.asarray(feats.mean(0), jnp.float32), jnp.asarray(np.maximum(feats.std(0), 1e-3), jnp.float32))


def initialise(params, cfg: FilterConfig, norm: Normaliser, problem: PlanningProblem, coeffs: jnp.ndarray) -> FilterInit:
    """How the projection of the batch ``coeffs`` (B, 2n) starts: per-sample gammas (B,), multipliers and first
    iterate (B, 2n) (see the module docstring). FilterError when the batch's coefficients are not the basis's."""
    if coeffs.ndim != 2 or coeffs.shape[-1] != cfg.num_coeffs:
        raise FilterError(f"the safety filter was trained for {cfg.num_coeffs} coefficients per trajectory (basis order "
                          f"{cfg.basis.order}); this planner's batch has shape {tuple(coeffs.shape)}")
    feats = (raw_features(problem.observation, problem.init_y[0], coeffs, cfg) - norm.mean) / norm.std
    out = _network(cfg).apply({"params": params}, feats)
    gammas = cfg.gamma_min + (1.0 - cfg.gamma_min) * jax.nn.sigmoid(out[:, :GAMMA_OUTPUTS])
    n2 = cfg.num_coeffs
    multipliers = cfg.multiplier_scale * out[:, GAMMA_OUTPUTS:GAMMA_OUTPUTS + n2]
    first = coeffs + cfg.coeff_scale * out[:, GAMMA_OUTPUTS + n2:]
    return FilterInit(gammas[:, 0], gammas[:, 1], first, multipliers)


def empty_state(cfg: FilterConfig) -> dict[str, Any]:
    """The structure of a filter checkpoint's state (parameters and normaliser; shapes only, traced), for restoring."""
    vector = jax.ShapeDtypeStruct((cfg.input_dim,), jnp.float32)
    return {"params": parameter_shapes(init_params, cfg),
            "normaliser": Normaliser(vector, vector)}


def load_filter(path: str | Path, lanes: int | None = None) -> tuple[FilterConfig, Any, Normaliser, dict[str, Any]]:
    """(config, params, normaliser, meta) of a filter checkpoint; CheckpointError when unusable (corrupted, another
    kind, arrays of other shapes, non-finite weights), or when ``lanes`` is given and it was trained for roads with
    other lane counts."""
    meta, state = load_checkpoint(path, CHECKPOINT_KIND, lanes)
    cfg = header_config(meta, path, FilterConfig, "safety-filter")
    target = empty_state(cfg)
    restored = restore(target, {k: state.get(k) for k in target}, path, "the safety-filter state")
    norm = Normaliser(*restored["normaliser"])
    check_scales(path, "the safety-filter state", {"normaliser.std": norm.std})
    return cfg, restored["params"], norm, meta
