"""Gaussian priors: P1's independent set-points, and driveopt's share of coherent whole-horizon behaviours."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from driveopt.config import ProjectionConfig, SamplerConfig
from driveopt.priors.base import Proposal, clip_setpoints, default_mean
from driveopt.problem import PlanningProblem
from driveopt.qp import NUM_SEGMENTS
from driveopt.sampler import sample_gaussian


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
