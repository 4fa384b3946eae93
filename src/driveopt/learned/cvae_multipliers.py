"""The CVAE of P2's reference [5] (Shrestha et al., IROS 2023): set-points AND the projection's initial multipliers,
trained through the set-point QP and the unrolled batch projection.

    encoder (observation o, expert trajectory tau_e) -> (mu_z, log sigma_z^2)      P1's CVAE encoder (driveopt.learned.cvae)
    decoder (z, o) -> set-points p -> set-point QP -> xi                           P1's CVAE decoder
    multiplier head (o, xi) -> lambda_0 (2n: one per Bernstein coefficient, x then y)
    projection (driveopt.projection.project, unrolled) from lambda_0 -> xi*

Loss, a mean over rows (one z per row, reparameterised; :func:`loss_terms`)::

    L = MSE(W xi*, tau_e) + beta * KL + residual_weight * r(xi*) + velocity_weight * |speed(xi*) - v_des|

with MSE the mean over the 2K coordinates [m^2] (x and y at every node), KL [nats] summed over the latent, r the
total constraint residual of the projected trajectory (the planner's families, each an L2 norm over the nodes, summed
as ranked) and the last term the L2 norm over the nodes of the speed error [m/s].

[5]'s decoder predicts the multipliers from (z, o) together with the set-points. Here a head reads them from
(o, xi), xi the sample's set-point-QP trajectory: the same information on the decoder's samples (xi is an affine,
one-to-one function of p, and p of z), and the planner's safety-filter contract (:mod:`driveopt.filtering`: every
batch's coefficients in, their initialisation out) keeps each sample's multipliers paired with its own set-points,
in every batch and for rows that come from elsewhere (the stops, the previous plan), without passing latents
through the optimiser. The head's output layer starts at zero: the untrained model projects from zero multipliers,
as the plain planner does. docs/design.md lists every choice where [5] is silent or driveopt departs.

Inputs are standardised with statistics of the training data (:class:`Normaliser`, saved with the weights): the
CVAE's (:func:`driveopt.learned.cvae.fit_normaliser`) and the coefficients', x in the planning frame and y relative
to the ego's current y.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from driveopt.checks import ConfigError, check_count, check_number, check_parameters, dense_parameters
from driveopt.config import PlannerConfig
from driveopt.files import shipped_weights_file
from driveopt.filtering import FilterError
from driveopt.learned import cvae
from driveopt.learned.checkpoint import check_scales, header_config, load_checkpoint, parameter_shapes, restore
from driveopt.planner import setpoint_batch
from driveopt.problem import PlanningProblem
from driveopt.projection import project
from driveopt.qp import make_model
from driveopt.trajectory import evaluate

CHECKPOINT_KIND = "cvae-multipliers"
SHIPPED = {4: "cvae-multipliers-four-lane.ckpt"}  # lanes -> file in driveopt/weights
MULTIPLIER_HEAD = "multipliers"  # the head's parameters in the params dict (beside "encoder" and "decoder")


@dataclasses.dataclass(frozen=True)
class MultiplierCVAEConfig:
    cvae: cvae.CVAEConfig = cvae.CVAEConfig()  # encoder and set-point decoder (its qp section is not used: the
    # planner's set-point QP is, see driveopt.training.cvae_multipliers)
    multiplier_hidden: tuple[int, ...] = (256, 256)  # [-] widths of the multiplier head's MLP
    multiplier_scale: float = 1.0  # [m] initial multipliers = multiplier_scale * head output (coefficient units)

    def __post_init__(self):
        if not self.multiplier_hidden:
            raise ConfigError("MultiplierCVAEConfig.multiplier_hidden needs at least one width")
        for width in self.multiplier_hidden:
            check_count("MultiplierCVAEConfig.multiplier_hidden widths", width)
        check_number("MultiplierCVAEConfig.multiplier_scale", self.multiplier_scale, 0.0, low_open=True, unit="m")
        check_parameters("MultiplierCVAEConfig", self.parameter_count)

    @property
    def num_coeffs(self) -> int:
        """2n: coefficients of one trajectory (both axes)."""
        return 2 * self.cvae.basis.num_coeffs

    @property
    def head_input_dim(self) -> int:
        return cvae.FEATURE_DIM + self.num_coeffs

    @property
    def parameter_count(self) -> int:
        """[-] weights of encoder, decoder and multiplier head (LayerNorm scales aside)."""
        return self.cvae.parameter_count + dense_parameters([self.head_input_dim, *self.multiplier_hidden, self.num_coeffs])

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "MultiplierCVAEConfig":
        data = dict(data)
        inner = cvae.CVAEConfig.from_dict(data.pop("cvae", {}))
        if "multiplier_hidden" in data:
            data["multiplier_hidden"] = tuple(int(w) for w in data["multiplier_hidden"])
        return cls(cvae=inner, **data)


class Normaliser(NamedTuple):
    """Standardisation statistics (a pytree): the CVAE's four fields (:class:`driveopt.learned.cvae.Normaliser`, read
    by its encoder and decoder by name) and the coefficients' (x in the planning frame, y relative to the ego)."""

    feature_mean: jnp.ndarray  # (FEATURE_DIM,)
    feature_std: jnp.ndarray
    trajectory_mean: jnp.ndarray  # (cfg.cvae.trajectory_features,)
    trajectory_std: jnp.ndarray
    coeff_mean: jnp.ndarray  # (2n,) [m]
    coeff_std: jnp.ndarray  # (2n,) [m]


class Batch(NamedTuple):
    """Training rows (R leading) with their planning problems: everything the loss needs."""

    problem: PlanningProblem  # stacked, R leading (driveopt.data.replay.problem_from_row)
    trajectory: jnp.ndarray  # (R, K, 2) [m] expert plan, x relative to the ego


def _head(cfg: MultiplierCVAEConfig) -> cvae.MLP:
    """The multiplier head: the CVAE's MLP with its output layer initialised at zero."""
    return cvae.MLP(cfg.multiplier_hidden, cfg.num_coeffs, zero_output=True)


def init_params(cfg: MultiplierCVAEConfig, key: jax.Array) -> dict[str, Any]:
    k_cvae, k_head = jax.random.split(key)
    head = _head(cfg).init(k_head, jnp.zeros((1, cfg.head_input_dim)))["params"]
    return {**cvae.init_params(cfg.cvae, k_cvae), MULTIPLIER_HEAD: head}


def relative_coeffs(coeffs: jnp.ndarray, ego_y: jnp.ndarray, cfg: MultiplierCVAEConfig) -> jnp.ndarray:
    """(..., 2n) coefficients with y relative to ``ego_y`` [m] (x is already relative: the planning frame)."""
    n = cfg.cvae.basis.num_coeffs
    return jnp.concatenate([coeffs[..., :n], coeffs[..., n:] - jnp.asarray(ego_y)[..., None]], axis=-1)


def fit_normaliser(observation: np.ndarray, trajectory: np.ndarray, coeffs: np.ndarray, ego_y: np.ndarray,
                   cfg: MultiplierCVAEConfig) -> Normaliser:
    """Statistics (standard deviations floored at 1e-3) of rows of observations (R, 55), expert trajectories
    (R, K, 2) [m], their coefficients (R, 2n) [m] (they stand for the samples) and ego lateral positions (R,) [m]."""
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    rows = cvae.Batch(f32(observation), f32(trajectory), None, None, None)
    base = cvae.fit_normaliser(rows, cfg.cvae)
    rel = np.asarray(relative_coeffs(f32(coeffs), f32(ego_y), cfg))
    return Normaliser(*base, f32(rel.mean(0)), f32(np.maximum(rel.std(0), 1e-3)))


def multipliers(params, cfg: MultiplierCVAEConfig, norm: Normaliser, problem: PlanningProblem, coeffs: jnp.ndarray) -> jnp.ndarray:
    """(B, 2n) initial multipliers [m] of the projection of the batch ``coeffs`` (B, 2n) for ``problem``; FilterError
    when the batch's coefficients are not the basis's."""
    if coeffs.ndim != 2 or coeffs.shape[-1] != cfg.num_coeffs:
        raise FilterError(f"the cvae-multipliers model was trained for {cfg.num_coeffs} coefficients per trajectory "
                          f"(basis order {cfg.cvae.basis.order}); this planner's batch has shape {tuple(coeffs.shape)}")
    obs = (cvae.observation_features(problem.observation, cfg.cvae.position_clip) - norm.feature_mean) / norm.feature_std
    xi = (relative_coeffs(coeffs, problem.init_y[0], cfg) - norm.coeff_mean) / norm.coeff_std
    feats = jnp.concatenate([jnp.broadcast_to(obs, (coeffs.shape[0], obs.shape[-1])), xi], axis=-1)
    return cfg.multiplier_scale * _head(cfg).apply({"params": params[MULTIPLIER_HEAD]}, feats)


def lane_bounds(problem: PlanningProblem) -> jnp.ndarray:
    """(2,) [m] (y_lb, y_ub) of the ego centre: the decoder bounds its lateral set-points to them."""
    return jnp.stack([problem.y_lb, problem.y_ub])


def sample_setpoints(params, cfg: MultiplierCVAEConfig, norm: Normaliser, problem: PlanningProblem, key: jax.Array,
                     num: int) -> jnp.ndarray:
    """(num, 8) set-points for ``problem`` from z ~ N(0, I) (the planner's first batch)."""
    return cvae.sample_setpoints(params, cfg.cvae, norm, problem.observation, lane_bounds(problem), key, num)


def row_terms(params, cfg: MultiplierCVAEConfig, norm: Normaliser, problem: PlanningProblem, trajectory: jnp.ndarray,
              key: jax.Array, config: PlannerConfig) -> dict[str, jnp.ndarray]:
    """The loss terms of one row: z from q(z | o, tau_e), its set-points through the planner's set-point QP, the head's
    multipliers, ``config.projection.max_iterations`` unrolled projection iterations from them."""
    obs = problem.observation[None]
    mu, log_var = cvae.encode(params, cfg.cvae, norm, obs, trajectory[None])
    z = mu + jnp.exp(0.5 * log_var) * jax.random.normal(key, mu.shape, mu.dtype)
    setpoints = cvae.decode_setpoints(params, cfg.cvae, norm, z, obs, lane_bounds(problem)[None])
    model = make_model(config.basis, config.qp)
    qp_coeffs, b_x, b_y = setpoint_batch(model, problem, config, setpoints)
    lam = multipliers(params, cfg, norm, problem, qp_coeffs)
    proj = project(model, problem, qp_coeffs, b_x, b_y, config.projection, init_multipliers=lam, unroll=True)
    traj = evaluate(model, proj.coeffs[0])
    squared = (traj.x - trajectory[:, 0]) ** 2 + (traj.y - trajectory[:, 1]) ** 2
    return {"reconstruction": 0.5 * jnp.mean(squared),
            "kl": 0.5 * jnp.sum(mu[0] ** 2 + jnp.exp(log_var[0]) - 1.0 - log_var[0]),
            "residual": proj.residuals.total[0],
            "velocity": jnp.sqrt(jnp.sum((traj.speed - problem.v_des) ** 2)),
            "feasible": (proj.residuals.total[0] <= config.sampler.residual_tolerance).astype(jnp.float32)}


def batch_terms(params, cfg: MultiplierCVAEConfig, norm: Normaliser, batch: Batch, key: jax.Array,
                config: PlannerConfig) -> dict[str, jnp.ndarray]:
    """:func:`row_terms` of every row (one key per row, split from ``key``), each (R,)."""
    keys = jax.random.split(key, batch.trajectory.shape[0])
    return jax.vmap(lambda p, t, k: row_terms(params, cfg, norm, p, t, k, config))(batch.problem, batch.trajectory, keys)


def loss_terms(params, cfg: MultiplierCVAEConfig, norm: Normaliser, batch: Batch, key: jax.Array,
               config: PlannerConfig) -> dict[str, jnp.ndarray]:
    """Means over the rows of :func:`batch_terms`."""
    return {name: jnp.mean(value) for name, value in batch_terms(params, cfg, norm, batch, key, config).items()}


def loss(params, cfg: MultiplierCVAEConfig, norm: Normaliser, batch: Batch, key: jax.Array, config: PlannerConfig,
         beta, residual_weight, velocity_weight):
    """(loss, terms): reconstruction + beta KL + residual_weight residual + velocity_weight velocity (module docstring)."""
    terms = loss_terms(params, cfg, norm, batch, key, config)
    value = (terms["reconstruction"] + beta * terms["kl"] + residual_weight * terms["residual"]
             + velocity_weight * terms["velocity"])
    return value, terms


def empty_state(cfg: MultiplierCVAEConfig) -> dict[str, Any]:
    """The structure of a checkpoint's state (parameters and normaliser; shapes only, traced), for restoring."""
    vec = lambda n: jax.ShapeDtypeStruct((n,), jnp.float32)  # noqa: E731
    traj = cfg.cvae.trajectory_features
    return {"params": parameter_shapes(init_params, cfg),
            "normaliser": Normaliser(vec(cvae.FEATURE_DIM), vec(cvae.FEATURE_DIM), vec(traj), vec(traj),
                                     vec(cfg.num_coeffs), vec(cfg.num_coeffs))}


def shipped_weights(lanes: int) -> Path | None:
    """Path of the weights shipped for roads with ``lanes`` lanes (four), or None."""
    return shipped_weights_file(SHIPPED, lanes)


def weights_file(lanes: int, weights: str | Path | None) -> Path | None:
    """``weights`` when given, else the file shipped for roads with ``lanes`` lanes, else None."""
    return Path(weights) if weights else shipped_weights(lanes)


def load_model(path: str | Path, lanes: int | None = None) -> tuple[MultiplierCVAEConfig, Any, Normaliser, dict[str, Any]]:
    """(config, params, normaliser, meta) of a cvae-multipliers checkpoint; CheckpointError when unusable, or when
    ``lanes`` is given and it was trained for roads with other lane counts."""
    meta, state = load_checkpoint(path, CHECKPOINT_KIND, lanes)
    cfg = header_config(meta, path, MultiplierCVAEConfig, "cvae-multipliers")
    target = empty_state(cfg)
    restored = restore(target, {k: state.get(k) for k in target}, path, "the cvae-multipliers state")
    norm = Normaliser(*restored["normaliser"])
    check_scales(path, "the cvae-multipliers state", cvae.normaliser_scales(norm))
    return cfg, restored["params"], norm, meta
