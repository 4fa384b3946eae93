"""The sampling distribution of the bi-level optimiser (P1 Alg. 1, eq. 6).

Set-points are ``p = (v_1..v_4 [m/s], y_1..y_4 [m])``: desired speed and lateral position (road frame) for each
quarter of the horizon. The first batch of a planning call comes from a *prior*: any JAX pytree with
``propose(problem, key, num, warm_mean) -> Proposal``. The planner passes it through ``jit`` as data, so a learned
prior (:mod:`driveopt.priors`) carries its weights as leaves and slots in without any change to the optimiser; its
static fields (dataclass fields marked ``static``) are part of the compiled function's key. :class:`GaussianPrior`
is the default. Later iterations sample the Gaussian ``N(mean, cov)`` that the first proposal's moments initialise
and :func:`cem_update` adapts over the elite set.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple, Protocol

import jax
import jax.numpy as jnp

from driveopt.config import ProjectionConfig, SamplerConfig
from driveopt.problem import PlanningProblem
from driveopt.qp import NUM_SEGMENTS


class Proposal(NamedTuple):
    samples: jnp.ndarray  # (num, 8) set-points
    mean: jnp.ndarray  # (8,) mean of the distribution they came from
    cov: jnp.ndarray  # (8, 8) its covariance


class Prior(Protocol):
    def propose(self, problem: PlanningProblem, key: jax.Array, num: int, warm_mean: jnp.ndarray | None) -> Proposal:
        """``num`` set-points; ``warm_mean`` None means :func:`default_mean` (a prior centred on the warm start
        centres on it; the planner passes that value for an absent ``WarmStart``)."""
        ...


def clip_setpoints(p: jnp.ndarray, problem: PlanningProblem, v_max: float) -> jnp.ndarray:
    """Keep speeds in [0, v_max] [m/s] and lateral set-points inside the lane bounds [m]."""
    v = jnp.clip(p[..., :NUM_SEGMENTS], 0.0, v_max)
    y = jnp.clip(p[..., NUM_SEGMENTS:], problem.y_lb, problem.y_ub)
    return jnp.concatenate([v, y], axis=-1)


def moments(samples: jnp.ndarray, jitter: float) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(mean (8,), covariance (8, 8)) of ``samples`` (num, 8), ``jitter`` added to the covariance diagonal."""
    mean = jnp.mean(samples, axis=0)
    centred = samples - mean
    cov = centred.T @ centred / samples.shape[0] + jitter * jnp.eye(samples.shape[1], dtype=samples.dtype)
    return mean, cov


def default_mean(problem: PlanningProblem) -> jnp.ndarray:
    """Current speed and lateral position, held over the horizon."""
    speed = jnp.hypot(problem.init_x[1], problem.init_y[1])
    return jnp.concatenate([jnp.full(NUM_SEGMENTS, speed), jnp.full(NUM_SEGMENTS, problem.init_y[0])])


def sample_gaussian(key: jax.Array, mean: jnp.ndarray, cov: jnp.ndarray, num: int) -> jnp.ndarray:
    """(num, 8) draws of N(mean, cov); cov is symmetrised and floored on its diagonal first."""
    cov = 0.5 * (cov + cov.T) + 1e-6 * jnp.eye(cov.shape[0], dtype=cov.dtype)
    chol = jnp.linalg.cholesky(cov)
    return mean + jax.random.normal(key, (num, mean.shape[0]), mean.dtype) @ chol.T


def select_lowest(values: jnp.ndarray, count: int) -> jnp.ndarray:
    """Indices of the ``count`` smallest values, smallest first."""
    return jax.lax.top_k(-values, count)[1]


def elite_weights(elite_costs: jnp.ndarray, temperature: float) -> jnp.ndarray:
    """The elites' weights in P1 eq. 6, exp(-(c - min c) / temperature) normalised (the minimum subtracted first)."""
    weights = jnp.exp(-(elite_costs - jnp.min(elite_costs)) / temperature)
    return weights / jnp.sum(weights)


def cem_update(
    mean: jnp.ndarray, cov: jnp.ndarray, elites: jnp.ndarray, elite_costs: jnp.ndarray, cfg: SamplerConfig
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """P1 eq. 6 with :func:`elite_weights`."""
    weights = elite_weights(elite_costs, cfg.temperature)
    new_mean = (1.0 - cfg.learning_rate) * mean + cfg.learning_rate * weights @ elites
    centred = elites - new_mean
    spread = (weights[:, None] * centred).T @ centred
    new_cov = (1.0 - cfg.learning_rate) * cov + cfg.learning_rate * spread
    new_cov = new_cov + cfg.covariance_jitter * jnp.eye(mean.shape[0], dtype=mean.dtype)
    return new_mean, new_cov


def coherent_behaviours(problem: PlanningProblem, key: jax.Array, num: int, speed_std: float) -> jnp.ndarray:
    """(num, 8) whole-horizon behaviours: one speed ~ N(current, speed_std) held in every quarter, and a
    lane centre (uniform over the lanes) reached from the quarter drawn uniformly, current y before it."""
    k_speed, k_lane, k_when = jax.random.split(key, 3)
    speed = jnp.hypot(problem.init_x[1], problem.init_y[1]) + speed_std * jax.random.normal(k_speed, (num, 1))
    lane = jax.random.randint(k_lane, (num, 1), 0, problem.num_lanes.astype(jnp.int32))
    centre = problem.lane_center0 + problem.lane_width * lane
    change = jax.random.randint(k_when, (num, 1), 0, NUM_SEGMENTS)
    quarter = jnp.arange(NUM_SEGMENTS)[None, :]
    lateral = jnp.where(quarter < change, problem.init_y[0], centre)
    return jnp.concatenate([jnp.broadcast_to(speed, (num, NUM_SEGMENTS)), lateral], axis=1)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class GaussianPrior:
    """Diagonal Gaussian around the warm-start mean (or the current speed and lane position).

    P1 samples every set-point independently. With ``structured_fraction`` > 0 that share of the
    first batch is instead drawn as coherent behaviours (:func:`coherent_behaviours`): in dense
    traffic the feasible plans (follow the leader, change into a gap) are whole-horizon
    behaviours that independent draws almost never produce. 0 gives P1's prior exactly.
    """

    speed_std: float = dataclasses.field(default=SamplerConfig.speed_std, metadata=dict(static=True))  # [m/s]
    lateral_std: float = dataclasses.field(default=SamplerConfig.lateral_std, metadata=dict(static=True))  # [m]
    v_max: float = dataclasses.field(default=ProjectionConfig.v_max, metadata=dict(static=True))  # [m/s]
    structured_fraction: float = dataclasses.field(default=0.5, metadata=dict(static=True))  # [-]

    @classmethod
    def from_config(cls, sampler: SamplerConfig, v_max: float) -> "GaussianPrior":
        return cls(sampler.speed_std, sampler.lateral_std, v_max, sampler.structured_fraction)

    def covariance(self) -> jnp.ndarray:
        var = jnp.array([self.speed_std**2] * NUM_SEGMENTS + [self.lateral_std**2] * NUM_SEGMENTS, jnp.float32)
        return jnp.diag(var)

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        mean = default_mean(problem) if warm_mean is None else warm_mean
        cov = self.covariance()
        k_gauss, k_struct = jax.random.split(key)
        samples = sample_gaussian(k_gauss, mean, cov, num)
        structured = int(round(self.structured_fraction * num))
        if structured:
            samples = samples.at[num - structured:].set(coherent_behaviours(problem, k_struct, structured, self.speed_std))
        return Proposal(clip_setpoints(samples, problem, self.v_max), mean, cov)
