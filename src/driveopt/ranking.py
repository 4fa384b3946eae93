"""How the rows of a sampler batch are ranked: the key that picks the plan, and the elite sets the sampler adapts to.

Every row of a batch has a weighted driving cost ``c`` and a total constraint residual ``r`` after projection; it is
*feasible* when ``r`` is within ``sampler.residual_tolerance``. A ranking turns them into

- a **score** ``w c + r`` (``cost_weight`` w): what the cross-entropy update weighs the elites by (P1 eq. 6);
- a **key**: what the pick of a batch, the best over the iterations and the fallback's choice minimise;
- the **elite set** of ``sampler.num_elites`` rows out of the ``sampler.num_constraint_elites`` constraint elites.

Three rankings exist. :class:`FeasibilityFirst` (driveopt's default) puts every feasible row ahead of every infeasible
one. :class:`CostPlusResidual` is P1's: the lowest residuals, then the lowest score among them, feasible or not.
:class:`P1AuthorsRanking` is P1's with its authors' driving cost in place of driveopt's.
Rankings are frozen dataclasses: :func:`driveopt.planner.solve` takes one as a static argument, so each is one
compilation.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import jax.numpy as jnp

from driveopt.checks import check_number
from driveopt.config import MAX_WEIGHT, CostConfig
from driveopt.costs import weighted_cost
from driveopt.problem import PlanningProblem
from driveopt.sampler import select_lowest
from driveopt.trajectory import Trajectory

INFEASIBLE_PENALTY = 1e6  # [-] added to the key of an infeasible row (FeasibilityFirst): feasible ones rank first


class Candidate(NamedTuple):
    """One ranked row of a batch."""

    score: jnp.ndarray  # () the ranking key (Ranking.key) of the row
    feasible: jnp.ndarray  # () bool: total residual within sampler.residual_tolerance
    setpoints: jnp.ndarray  # (8,)
    coeffs: jnp.ndarray  # (2n,)
    residuals: jnp.ndarray  # (4,) per family (driveopt.projection.FAMILIES)
    terms: jnp.ndarray  # (len(COST_TERMS),) unweighted cost terms
    cost: jnp.ndarray  # () weighted cost


class Ranking(Protocol):
    def driving_cost(self, traj: Trajectory, problem: PlanningProblem, terms: dict[str, jnp.ndarray],
                     weights: CostConfig) -> jnp.ndarray:
        """(B,) the driving cost of the rows ``traj`` that the score weighs; ``terms``: driveopt's cost terms of them
        (:func:`driveopt.costs.cost_terms`), ``weights``: the planner's cost weights."""
        ...

    def score(self, cost: jnp.ndarray, residual: jnp.ndarray) -> jnp.ndarray:
        """(B,) the score of rows with weighted driving ``cost`` and total ``residual``."""
        ...

    def key(self, score: jnp.ndarray, residual: jnp.ndarray, feasible: jnp.ndarray) -> jnp.ndarray:
        """(B,) what the pick minimises, from the rows' scores, total residuals and feasibility."""
        ...

    def elites(self, key: jnp.ndarray, residual: jnp.ndarray, score: jnp.ndarray, feasible: jnp.ndarray,
               num_constraint_elites: int, num_elites: int) -> jnp.ndarray:
        """(num_elites,) indices of the elite set; ``key`` and ``residual`` are +inf for rows never ranked."""
        ...


@dataclass(frozen=True)
class _WeightedScore:
    cost_weight: float = 1.0  # [-] w of the score w * cost + residual

    def __post_init__(self) -> None:
        check_number("ranking.cost_weight", self.cost_weight, 0.0, MAX_WEIGHT, low_open=True)

    def driving_cost(self, traj, problem, terms, weights) -> jnp.ndarray:
        """driveopt's weighted driving cost."""
        return weighted_cost(terms, weights)

    def score(self, cost: jnp.ndarray, residual: jnp.ndarray) -> jnp.ndarray:
        """``w * cost + residual`` of rows with weighted driving ``cost`` and total ``residual``."""
        return self.cost_weight * cost + residual


@dataclass(frozen=True)
class FeasibilityFirst(_WeightedScore):
    """Feasible rows first, by score; infeasible ones after them, by residual (driveopt's default).

    The constraint elites are the lowest keys, where every feasible row ranks ahead of every infeasible one; the elite
    set is the lowest scores of those, feasible rows always ahead. So a batch with any feasible row never picks an
    infeasible one, and a batch without one picks the row closest to the constraints."""

    def key(self, score: jnp.ndarray, residual: jnp.ndarray, feasible: jnp.ndarray) -> jnp.ndarray:
        return jnp.where(feasible, score, INFEASIBLE_PENALTY + residual)

    def elites(self, key, residual, score, feasible, num_constraint_elites: int, num_elites: int) -> jnp.ndarray:
        constraint_elites = select_lowest(key, num_constraint_elites)
        elite_key = jnp.where(feasible, score - INFEASIBLE_PENALTY, score)
        return constraint_elites[select_lowest(elite_key[constraint_elites], num_elites)]


@dataclass(frozen=True)
class CostPlusResidual(_WeightedScore):
    """P1's ranking (Alg. 1): the ``num_constraint_elites`` lowest residuals, the ``num_elites`` lowest scores of
    those, and the lowest score is picked, feasible or not. P1's authors weigh the cost 1e-5 on driveopt's scale
    (``driveopt.registry.P1_RANKING_COST_WEIGHT``), so the residual leads and the cost separates equal residuals."""

    def key(self, score: jnp.ndarray, residual: jnp.ndarray, feasible: jnp.ndarray) -> jnp.ndarray:
        return score

    def elites(self, key, residual, score, feasible, num_constraint_elites: int, num_elites: int) -> jnp.ndarray:
        constraint_elites = select_lowest(residual, num_constraint_elites)
        return constraint_elites[select_lowest(score[constraint_elites], num_elites)]


P1_FREE_HEADING = math.radians(10.0)  # [rad] heading to the road P1's authors' cost leaves free (expert_mpc/*.py)
P1_STEERING_WEIGHT = 0.01  # [-] their weight of the steering angle's and its differences' norms
P1_WHEEL_BASE = 2.5  # [m] their steering angle: arctan(wheel base x curvature)


@dataclass(frozen=True)
class P1AuthorsRanking(CostPlusResidual):
    """P1's ranking with its authors' driving cost (``compute_cost`` of every ``expert_mpc/expert_*.py``):
    ``speed_weight ||v_x - v_des|| + 0.01 (||steering|| + ||steering differences||) + ||max(0, |heading| - 10°)||``,
    norms over the plan's nodes, steering ``arctan(2.5 m x curvature)``, heading the velocity's angle to the road; the
    score adds the residual (``cost_weight`` 1).

    The heading term weighs as much as the residual and keeps the pick within 10° of the road; driveopt's cost scaled by
    the speed weight (:class:`CostPlusResidual`) would scale it away too (docs/findings/faithful-drift.md)."""

    speed_weight: float = 1e-3  # [s/m] the authors' velocity_scaling: 1e-5 MPC-Random and -Vanilla, 1e-2 MPC-Grid,
    # 1e-3 MPC-Bi-Level

    def __post_init__(self) -> None:
        super().__post_init__()
        check_number("ranking.speed_weight", self.speed_weight, 0.0, MAX_WEIGHT)

    def driving_cost(self, traj, problem, terms, weights) -> jnp.ndarray:
        norm = functools.partial(jnp.linalg.norm, axis=-1)
        steering = jnp.arctan(P1_WHEEL_BASE * traj.curvature)
        return (self.speed_weight * norm(traj.vx - problem.v_des)
                + P1_STEERING_WEIGHT * (norm(steering) + norm(jnp.diff(steering, axis=-1)))
                + norm(jnp.maximum(jnp.abs(traj.heading) - P1_FREE_HEADING, 0.0)))


P2_WHEEL_BASE = 2.875  # [m] P2's authors' steering angle: arctan(wheel base x curvature) (DOptimizerJax.py wheel_base)
P2_STEERING_WEIGHT = 0.01  # [-] their weight of the steering norms and of the heading term


@dataclass(frozen=True)
class P2AuthorsRanking(CostPlusResidual):
    """P2's ranking with its authors' cost (``compute_cost`` of VQOptMain's ``model/DOptimizerJax.py``): the score
    ``r + exp(-gate r) c`` with ``c = progress_weight ||x - v_des T|| + 0.01 (||steering|| + ||steering differences||
    + ||max(0, |heading| - 10°)||)``, norms over the plan's nodes, x the position along the road at each node, T the
    horizon (a progress term: the further a plan gets, the lower), steering ``arctan(2.875 m x curvature)``.

    The gate ``exp(-2 r)`` fades the cost of a row as its residual grows, so an all-infeasible batch picks the row
    nearest the constraints rather than the one that gets furthest; the authors gate the progress term only, this
    gates the whole cost (the steering and heading terms weigh 0.01 and change no pick measurably)."""

    progress_weight: float = 1e-3  # [1/m] the authors' weight of ||x - v_des T||
    gate: float = 2.0  # [-] the cost is weighed by exp(-gate x residual) (0: ungated, as their DOptimizerJax3.py)

    def __post_init__(self) -> None:
        super().__post_init__()
        check_number("ranking.progress_weight", self.progress_weight, 0.0, MAX_WEIGHT)
        check_number("ranking.gate", self.gate, 0.0, MAX_WEIGHT)

    def driving_cost(self, traj, problem, terms, weights) -> jnp.ndarray:
        norm = functools.partial(jnp.linalg.norm, axis=-1)
        steering = jnp.arctan(P2_WHEEL_BASE * traj.curvature)
        progress = norm(traj.x - problem.v_des * traj.t[..., -1:])
        return (self.progress_weight * progress
                + P2_STEERING_WEIGHT * (norm(steering) + norm(jnp.diff(steering, axis=-1))
                                        + norm(jnp.maximum(jnp.abs(traj.heading) - P1_FREE_HEADING, 0.0))))

    def score(self, cost: jnp.ndarray, residual: jnp.ndarray) -> jnp.ndarray:
        return self.cost_weight * jnp.exp(-self.gate * residual) * cost + residual
