"""One planning call: bi-level sampling optimiser (P1 Alg. 1) over set-point QP + batch projection.

    result = plan(problem, config, key=key)            # PlanResult (numpy; the host wrapper)
    result = plan(problem, config, key=key2, warm_start=result.mean)
    result = plan(problem, config, key=key3, previous=previous_plan(result, elapsed=0.1))
    solution = solve(problem, key, config, prior)      # Solution (JAX arrays): pure, jittable, differentiable

:func:`solve` is the optimiser itself: a pure function of arrays (``config`` static) whose status
is decided inside (``Solution.status``, a :class:`PlanStatus` value), so it can be jitted, vmapped
and differentiated (with ``unroll=True`` the projection runs a fixed number of iterations, which
reverse-mode differentiation needs). :func:`plan` validates the input, runs the compiled
``solve`` and returns a :class:`PlanResult` of numpy arrays in the road frame.

Per sampler iteration: draw set-points (the prior's proposal first, then the adapted Gaussian),
solve the set-point QP for the batch, project the batch onto the constraints, rank, and update the
Gaussian with P1 eq. 6 over the elite set. Ranking (``sampler.feasibility_first``, the default) puts
feasible samples (total residual within ``sampler.residual_tolerance``) first, by cost + residual;
infeasible ones follow, by residual for the constraint-elite set and by cost + residual within it,
as in P1. With ``feasibility_first`` False it is P1's ranking alone: the ``num_constraint_elites``
lowest residuals, the ``num_elites`` lowest cost + residual of those, and the lowest cost + residual
is picked, feasible or not. "cost" is ``sampler.ranking_cost_weight`` (default 1) times the driving cost
throughout: the ``-p1`` baselines weigh it 1e-5, as P1's authors' code lets the residual lead.

Rows appended to every batch (their :class:`RowKind` is in ``Snapshot.kind``) are ranked like any
sample: the previous replan's set-points when given, and, unless ``stop_rows`` is False (P1), a
comfortable stop at ``fallback_deceleration`` easing to the nearest lane centre and an emergency
stop at ``projection.a_max`` holding the current lateral position. The chosen trajectory is the
best candidate over all iterations by the same key (cost + residual, infeasible ones last when
feasibility comes first). The status is SUCCESS only when it is feasible; otherwise it is
INFEASIBLE, the chosen candidate (with feasibility first: the lowest-residual one) is reported, and
``result.fallback`` offers the stop that enters an obstacle's ellipse later, by the lower residual
when that ties (computed whether or not the stops ride in the batch; :mod:`driveopt.fallback`).

With ``sampler.refine_samples`` M > 0, each batch's M lowest-cost rows (whatever their residual) are projected
``sampler.refine_iterations`` more, from their iterate and multipliers, and a row takes its refined trajectory only
where that lowers its ranking key: the fast plans are the cheap ones and the ones that need the most iterations, so a
short projection of the whole batch plus a long one of a few rows recovers most of what a long projection of all buys.

Given the previous replan's plan (``previous``), the ``consistency`` cost term measures each
sample's lateral deviation from that plan: between two near-equal manoeuvres (pass left or right)
the one already begun keeps winning.

A safety filter (``safety_filter``; P2's learned one) is any pytree with
``initialise(problem, coeffs) -> FilterInit``: it sets the barrier parameters (per sample or per
batch; they replace ``projection.gamma_obs`` / ``gamma_lane``) and the projection's first iterate
and multipliers for every batch, appended rows included (:mod:`driveopt.safety`). With
``projection.max_iterations = 0`` nothing is projected and no filter is consulted: every row is
ranked as the set-point QP made it (P2 Fig. 9's "no filter").
"""

from __future__ import annotations

import dataclasses
import enum
import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from driveopt.config import PlannerConfig, SamplerConfig
from driveopt.costs import COST_TERMS, cost_terms, weighted_cost
from driveopt.fallback import (
    EVASIONS,
    HOLD,
    LANE_CENTRE,
    box_contact,
    braking_coeffs,
    first_contact,
    stop_setpoints,
    stop_trajectory,
)
from driveopt.filtering import SafetyFilter, check_filter_init
from driveopt.problem import PlanningProblem, check_problem
from driveopt.projection import FAMILIES, ProjectionResult, constraint_residuals, project
from driveopt.qp import (
    NUM_SEGMENTS,
    SETPOINT_DIM,
    boundary_values,
    fit_positions,
    initial_acceleration,
    make_model,
    solve_setpoint_qp,
)
from driveopt.sampler import GaussianPrior, Prior, cem_update, clip_setpoints, default_mean, sample_gaussian, select_lowest
from driveopt.scene import ProblemError
from driveopt.trajectory import Trajectory, evaluate
from driveopt.xla import XLA_CPU_COMPILER_OPTIONS, float32_products, supported_compiler_options

INFEASIBLE_PENALTY = 1e6  # [-] added to the ranking key of an infeasible sample (feasibility_first): feasible ones rank first


class PlanStatus(enum.IntEnum):
    SUCCESS = 0
    INFEASIBLE = 1
    NUMERICAL_ERROR = 2

    @property
    def message(self) -> str:
        return {
            PlanStatus.SUCCESS: "a sampled trajectory meets every constraint within the residual tolerance",
            PlanStatus.INFEASIBLE: "the chosen trajectory misses the residual tolerance (feasibility first: every sample did); "
                                   "use result.fallback",
            PlanStatus.NUMERICAL_ERROR: "the optimiser produced non-finite values; use result.fallback",
        }[self]


class RowKind(enum.IntEnum):
    """What a row of a sampler batch is (``Snapshot.kind``)."""

    SAMPLE = 0  # drawn from the prior or the adapted Gaussian
    PREVIOUS_PLAN = 1  # the previous replan's set-points (only when ``previous`` is given)
    COMFORTABLE_STOP = 2  # brake at ``fallback_deceleration`` towards the nearest lane centre
    EMERGENCY_STOP = 3  # brake at ``projection.a_max`` holding the current lateral position
    PLACEHOLDER = 4  # stands in for an absent previous plan (``PreviousPlan.absent``): a copy of the first sample, never ranked


class Snapshot(NamedTuple):
    """The whole batch of one sampler iteration (for plots, videos, and the multi-modal demonstrations of
    ``driveopt collect``: :mod:`driveopt.data.modes`); B rows, appended rows last."""

    setpoints: jnp.ndarray  # (B, 8)
    qp_coeffs: jnp.ndarray  # (B, 2n) set-point QP solutions
    projected_coeffs: jnp.ndarray  # (B, 2n) after projection
    residual: jnp.ndarray  # (B,) total residual after projection
    elite_index: jnp.ndarray  # (q,) indices of the elite set
    kind: jnp.ndarray  # (B,) RowKind of each row
    cost: jnp.ndarray  # (B,) weighted driving cost of each projected row (the ranking's cost, residual not added)


class History(NamedTuple):
    """Per-iteration scalars, each (num_iterations,)."""

    best_score: jnp.ndarray  # ranking key (Candidate.score) of the best candidate so far
    best_feasible: jnp.ndarray  # bool: the best candidate so far is feasible (what the status reports)
    elite_cost: jnp.ndarray  # mean cost + residual over the elite set
    min_residual: jnp.ndarray  # smallest total residual in the batch
    median_residual: jnp.ndarray  # median total residual in the batch
    num_feasible: jnp.ndarray  # samples within the residual tolerance
    projection_iterations: jnp.ndarray  # projection iterations run
    projection_status: jnp.ndarray  # ProjectionStatus value of the batch's projection


class PreviousPlan(NamedTuple):
    """The plan chosen by the previous replan, seen from this one.

    ``present`` False (:meth:`absent`) stands for "no previous plan" with the same array structure as a real one, so
    a closed loop's first call and its later calls are one compilation: the row it adds to the batch is a copy of the
    first sample that is never ranked, counted or refined, and the ``consistency`` term is zero, as without one."""

    setpoints: jnp.ndarray  # (8,) its set-points (re-solved from the current state as a candidate)
    lateral: jnp.ndarray  # (K,) [m] its lateral positions at this call's node times
    present: Any = True  # () bool: False for the placeholder of an absent plan

    @classmethod
    def absent(cls, num_nodes: int) -> "PreviousPlan":
        """The placeholder of a call without a previous plan (``num_nodes``: ``config.basis.num_nodes``)."""
        return cls(np.zeros(SETPOINT_DIM, np.float32), np.zeros(num_nodes, np.float32), np.False_)


class WarmStart(NamedTuple):
    """A warm start that may be absent (:meth:`absent`: the prior's own centre, ``default_mean``) with the array
    structure of a present one, so that a closed loop's first call and its later calls are one compilation."""

    mean: jnp.ndarray  # (8,) centre of the first proposal
    present: Any = True  # () bool

    @classmethod
    def absent(cls) -> "WarmStart":
        return cls(np.zeros(SETPOINT_DIM, np.float32), np.False_)


def previous_plan(result: "PlanResult", elapsed: float) -> PreviousPlan:
    """The executed plan of ``result`` (``safe_trajectory``) shifted by ``elapsed`` [s] to the next call's
    nodes; held at its last value beyond the horizon."""
    traj = result.safe_trajectory
    t = np.asarray(traj.t)
    lateral = np.interp(t + elapsed, t, np.asarray(traj.y)).astype(np.float32)
    return PreviousPlan(np.asarray(result.setpoints, dtype=np.float32), lateral, np.True_)


class Candidate(NamedTuple):
    """One ranked row of a batch."""

    score: jnp.ndarray  # () ranking key: cost + residual; with feasibility_first INFEASIBLE_PENALTY + residual when infeasible
    feasible: jnp.ndarray  # () bool: total residual within sampler.residual_tolerance
    setpoints: jnp.ndarray  # (8,)
    coeffs: jnp.ndarray  # (2n,)
    residuals: jnp.ndarray  # (4,) per family (driveopt.projection.FAMILIES)
    terms: jnp.ndarray  # (len(COST_TERMS),) unweighted cost terms
    cost: jnp.ndarray  # () weighted cost


class Solution(NamedTuple):
    """What :func:`solve` returns (JAX arrays, planning frame: the ego at x = 0)."""

    status: jnp.ndarray  # () int32 PlanStatus value, decided inside the jitted call
    best: Candidate  # the chosen candidate (lowest ranking key over all iterations)
    mean: jnp.ndarray  # (8,) final sampling mean
    cov: jnp.ndarray  # (8, 8) final sampling covariance
    history: History
    first: Snapshot
    last: Snapshot
    trajectory: Trajectory  # of the best coefficients
    fallback: Candidate  # the stop offered as fallback (its coefficients: the polynomial closest to it)
    fallback_trajectory: Trajectory  # the stop itself (driveopt.fallback): speed never increases, never below 0
    fallback_emergency: jnp.ndarray  # () bool: the fallback is the emergency stop


def goal_from_setpoints(setpoints: jnp.ndarray, init_x: jnp.ndarray, horizon: float) -> jnp.ndarray:
    """(B, 2) terminal goal (x_f, y_f) [m] implied by set-points: distance covered at the set speeds, last lateral."""
    quarter = horizon / NUM_SEGMENTS
    x_f = init_x[0] + quarter * jnp.sum(setpoints[:, :NUM_SEGMENTS], axis=1)
    return jnp.stack([x_f, setpoints[:, -1]], axis=1)


def _boundary(problem: PlanningProblem, cfg: PlannerConfig, setpoints: jnp.ndarray):
    """Equality right-hand sides; per sample when the QP imposes a terminal position (goal baseline)."""
    goal = goal_from_setpoints(setpoints, problem.init_x, cfg.basis.horizon) if cfg.qp.terminal_position else None
    return boundary_values(problem.init_x, problem.init_y, cfg.qp, goal)


def setpoint_batch(model, problem: PlanningProblem, cfg: PlannerConfig, setpoints: jnp.ndarray):
    """(coefficients (B, 2n), b_x, b_y) of the set-point QP for ``setpoints`` (B, 8), as every sampler batch solves it
    (the current state imposed; per-sample boundary rows only when the QP imposes a terminal position)."""
    b_x, b_y = _boundary(problem, cfg, setpoints)
    return solve_setpoint_qp(model, setpoints, b_x, b_y, initial_acceleration(problem.init_x, problem.init_y)), b_x, b_y


def project_batch(model, problem: PlanningProblem, cfg: PlannerConfig, qp_coeffs: jnp.ndarray, b_x, b_y,
                  safety_filter: SafetyFilter | None = None, unroll: bool = False) -> ProjectionResult:
    """The projection of a batch of set-point-QP solutions (B, 2n) as the planner runs it: set up by
    ``safety_filter`` when given (FilterError for outputs of the wrong shape), as configured otherwise; with
    ``projection.max_iterations = 0`` the batch comes back unprojected and the filter is not consulted."""
    if safety_filter is None or cfg.projection.max_iterations == 0:
        return project(model, problem, qp_coeffs, b_x, b_y, cfg.projection, unroll=unroll)
    init = check_filter_init(safety_filter.initialise(problem, qp_coeffs), qp_coeffs.shape)
    return project(model, problem, qp_coeffs, b_x, b_y, cfg.projection, gamma_obs=init.gamma_obs, gamma_lane=init.gamma_lane,
                   init_coeffs=init.coeffs, init_multipliers=init.multipliers, unroll=unroll)


def _iteration(model, problem, cfg: PlannerConfig, setpoints, previous: PreviousPlan | None, safety_filter, unroll: bool):
    """QP + projection + ranking for one batch of set-points (the appended rows: see the module docstring).

    Returns (pick, snapshot, score, stats): the best row, the batch, every row's cost + residual, and
    the iteration's History entries.
    """
    s = cfg.sampler
    stops = _stops(cfg) if cfg.stop_rows else ()
    num_samples = setpoints.shape[0]
    # An absent previous plan's row copies the first sample (the projection's batch-wide stop is unchanged) and is
    # excluded below wherever rows are ranked, counted or refined.
    appended = [] if previous is None else [jnp.where(previous.present, previous.setpoints, setpoints[0])[None]]
    appended += [stop_setpoints(problem, cfg.basis.horizon, *stop)[None] for stop in stops]
    kinds = [RowKind.SAMPLE] * num_samples + [RowKind.PREVIOUS_PLAN] * (previous is not None)
    kind = jnp.asarray(kinds + [RowKind.COMFORTABLE_STOP, RowKind.EMERGENCY_STOP][:len(stops)], jnp.int32)
    setpoints = jnp.concatenate([setpoints, *appended])
    placeholder = None
    if previous is not None:
        placeholder = (jnp.arange(setpoints.shape[0]) == num_samples) & ~previous.present
        kind = jnp.where(placeholder, RowKind.PLACEHOLDER, kind)
    qp_coeffs, b_x, b_y = setpoint_batch(model, problem, cfg, setpoints)
    row = (lambda b, i: b if b.ndim == 1 else b[i])  # noqa: E731  (boundary rows are per sample only for goals)
    for i, (decel, target) in zip(range(-len(stops), 0), stops):
        qp_coeffs = qp_coeffs.at[i].set(braking_coeffs(model, problem, decel, row(b_x, i), row(b_y, i), target))
    proj = project_batch(model, problem, cfg, qp_coeffs, b_x, b_y, safety_filter, unroll)
    lateral = None if previous is None else previous.lateral

    def terms_of(coeffs):
        traj = evaluate(model, coeffs)
        # without a previous plan every row is its own reference: consistency exactly 0 (selecting the reference,
        # not the term, leaves the arithmetic of a present plan's term as it was)
        return cost_terms(traj, problem, lateral if previous is None else jnp.where(previous.present, lateral, traj.y))

    terms = terms_of(proj.coeffs)
    if s.refine_samples and cfg.projection.max_iterations:
        proj, terms = _refine(model, problem, cfg, qp_coeffs, b_x, b_y, proj, terms, safety_filter, unroll, terms_of, placeholder)
    cost = weighted_cost(terms, cfg.cost)
    residual = proj.residuals.total
    score = s.ranking_cost_weight * cost + residual
    feasible = residual <= s.residual_tolerance
    key_score = _ranking_key(score, residual, feasible, s)
    if placeholder is not None:  # never ranked
        key_score, residual_key = jnp.where(placeholder, jnp.inf, key_score), jnp.where(placeholder, jnp.inf, residual)
        feasible_rows = feasible & ~placeholder
        # the median over the rows a call without the placeholder has
        median_residual = jnp.where(previous.present, jnp.median(residual), jnp.median(jnp.delete(residual, num_samples)))
    else:
        residual_key, feasible_rows, median_residual = residual, feasible, jnp.median(residual)
    if s.feasibility_first:
        # ConstraintEliteSet: lowest residuals, where every feasible sample ties, so feasible samples come
        # first ordered by score, then infeasible ones by residual.
        constraint_elites = select_lowest(key_score, s.num_constraint_elites)
        # EliteSet: lowest cost + residual of those (P1), feasible samples always ahead of infeasible ones.
        elite_key = jnp.where(feasible, score - INFEASIBLE_PENALTY, score)
    else:  # P1: the n lowest residuals, then the q lowest cost + residual of those
        constraint_elites = select_lowest(residual_key, s.num_constraint_elites)
        elite_key = score
    ranked = constraint_elites[select_lowest(elite_key[constraint_elites], s.num_elites)]

    pick = ranked[jnp.argmin(key_score[ranked])]
    families = jnp.stack(list(proj.residuals))  # (4, rows)
    term_values = jnp.stack([terms[k] for k in COST_TERMS])  # (terms, rows)

    def candidate(i):
        return Candidate(key_score[i], feasible[i], setpoints[i], proj.coeffs[i], families[:, i], term_values[:, i], cost[i])

    stats = History(
        best_score=key_score[pick], best_feasible=feasible[pick], elite_cost=jnp.mean(score[ranked]),
        min_residual=jnp.min(residual), median_residual=median_residual, num_feasible=jnp.sum(feasible_rows),
        projection_iterations=proj.iterations, projection_status=proj.status,
    )
    snapshot = Snapshot(setpoints, qp_coeffs, proj.coeffs, residual, ranked, kind, cost)
    return candidate(pick), snapshot, score, stats


def _refine(model, problem: PlanningProblem, cfg: PlannerConfig, qp_coeffs, b_x, b_y, proj: ProjectionResult, terms,
            safety_filter, unroll: bool, terms_of, placeholder) -> tuple[ProjectionResult, dict[str, jnp.ndarray]]:
    """``proj`` and its cost ``terms`` with the ``sampler.refine_samples`` lowest-cost rows (whatever their residual)
    projected ``sampler.refine_iterations`` more from where they stopped (iterate and multipliers; a filter's gammas),
    each row replaced only where that lowers its ranking key. The fast plans are the lowest-cost ones and the ones that
    need the most iterations to become feasible; a few more iterations for a few rows buy most of what more
    iterations for the whole batch would. ``terms_of``: cost terms of coefficients; ``placeholder``: rows never
    refined (or None)."""
    s = cfg.sampler

    def key(cost, residual):
        return _ranking_key(s.ranking_cost_weight * cost + residual, residual, residual <= s.residual_tolerance, s)

    cost = weighted_cost(terms, cfg.cost)
    rows = select_lowest(cost if placeholder is None else jnp.where(placeholder, jnp.inf, cost), s.refine_samples)
    gamma_obs = gamma_lane = None
    if safety_filter is not None:
        init = check_filter_init(safety_filter.initialise(problem, qp_coeffs[rows]), qp_coeffs[rows].shape)
        gamma_obs, gamma_lane = init.gamma_obs, init.gamma_lane
    pick = lambda b: b if b.ndim == 1 else b[rows]  # noqa: E731  (boundary rows are per sample only for goals)
    more = project(model, problem, qp_coeffs[rows], pick(b_x), pick(b_y),
                   dataclasses.replace(cfg.projection, max_iterations=s.refine_iterations), gamma_obs=gamma_obs,
                   gamma_lane=gamma_lane, init_coeffs=proj.coeffs[rows], init_multipliers=proj.multipliers[rows], unroll=unroll)
    more_terms = terms_of(more.coeffs)
    better = key(weighted_cost(more_terms, cfg.cost), more.residuals.total) < key(cost[rows], proj.residuals.total[rows])

    def merge(old, new):
        return old.at[rows].set(jnp.where(better.reshape((-1,) + (1,) * (new.ndim - 1)), new, old[rows]))

    refined = proj._replace(coeffs=merge(proj.coeffs, more.coeffs), multipliers=merge(proj.multipliers, more.multipliers),
                            residuals=jax.tree_util.tree_map(merge, proj.residuals, more.residuals))
    return refined, jax.tree_util.tree_map(merge, terms, more_terms)


def _stops(cfg: PlannerConfig) -> tuple[tuple[float, str], tuple[float, str]]:
    """(deceleration [m/s^2], lateral target) of the comfortable and of the emergency stop."""
    return (cfg.fallback_deceleration, LANE_CENTRE), (cfg.projection.a_max, HOLD)


def _ranking_key(score: jnp.ndarray, residual: jnp.ndarray, feasible: jnp.ndarray, s: SamplerConfig) -> jnp.ndarray:
    """What the pick and the best over iterations minimise: cost + residual (``score``, P1), with
    ``feasibility_first`` every infeasible row behind every feasible one (INFEASIBLE_PENALTY + residual)."""
    return jnp.where(feasible, score, INFEASIBLE_PENALTY + residual) if s.feasibility_first else score


def _fallback(model, problem: PlanningProblem, cfg: PlannerConfig) -> tuple[Candidate, jnp.ndarray, Trajectory]:
    """(candidate, emergency, trajectory) of the stop offered as fallback (:mod:`driveopt.fallback`): the one
    that enters an obstacle's ellipse latest (with ``fallback_evasion``: that touches a car's box latest, then enters
    its ellipse latest); on a tie (none does, or several at once) the one closest to meeting the constraints, the
    comfortable stop first among equals. The candidates are the comfortable and the emergency stop, and with
    ``fallback_evasion`` the emergency stops towards :data:`~driveopt.fallback.EVASIONS`, weighed only where both
    of those would touch a car's box (a car creeping in a jam, inside every ellipse but touching no box, would
    otherwise be steered sideways by the residual, step after step). Residuals and cost terms of all are measured in
    one batch, on their closest polynomials and their own paths."""
    t = jnp.asarray(model.t)
    standard = _stops(cfg)

    def stop(decel, target):  # (path, set-points) of one stop
        return (stop_trajectory(problem, t, decel, target, cfg.fallback_straightens),
                stop_setpoints(problem, cfg.basis.horizon, decel, target))

    parts = [jax.tree_util.tree_map(lambda a: a[None], stop(*s)) for s in standard]
    if cfg.fallback_evasion:  # the sideways stops in one traced copy (numeric targets), not one each
        parts.append(jax.vmap(functools.partial(stop, cfg.projection.a_max))(jnp.asarray(EVASIONS, dtype=jnp.float32)))
    every, setpoints = jax.tree_util.tree_map(lambda *a: jnp.concatenate(a), *parts)  # (stops, K) fields, (stops, 8)
    goal = jnp.stack([every.x[:, -1], every.y[:, -1]], axis=-1) if cfg.qp.terminal_position else None
    b_x, b_y = boundary_values(problem.init_x, problem.init_y, cfg.qp, goal)
    n = every.x.shape[0]
    coeffs = fit_positions(model, every.x, every.y, jnp.broadcast_to(b_x, (n, b_x.shape[-1])), jnp.broadcast_to(b_y, (n, b_y.shape[-1])))
    families = jnp.stack(list(constraint_residuals(model, problem, coeffs, cfg.projection)))  # (4, stops)
    terms = cost_terms(every, problem)
    cost = weighted_cost(terms, cfg.cost)
    total = jnp.sum(families, axis=0)
    feasible = total <= cfg.sampler.residual_tolerance
    score = _ranking_key(cfg.sampler.ranking_cost_weight * cost + total, total, feasible, cfg.sampler)
    contact = jax.vmap(lambda path: first_contact(problem, path))(every)
    if cfg.fallback_evasion:  # the box first, the ellipse on a tie; sideways stops only where both others touch a box
        nodes = model.t.shape[0]
        box = jax.vmap(lambda path: box_contact(problem, path))(every)
        sideways_weighed = jnp.all(box[:len(standard)] < nodes)
        contact = jnp.where((jnp.arange(n) < len(standard)) | sideways_weighed, contact + (nodes + 1) * box, -1)
    latest = contact == jnp.max(contact)
    pick = jnp.argmin(jnp.where(latest, total, jnp.inf))  # the first of equals
    term_values = jnp.stack([terms[k] for k in COST_TERMS])  # (terms, stops)
    candidate = Candidate(score[pick], feasible[pick], setpoints[pick], coeffs[pick], families[:, pick], term_values[:, pick], cost[pick])
    return candidate, pick > 0, jax.tree_util.tree_map(lambda a: a[pick], every)


def _better(a: Candidate, b: Candidate) -> Candidate:
    return jax.tree_util.tree_map(lambda u, v: jnp.where(a.score <= b.score, u, v), a, b)


def _all_finite(*arrays) -> jnp.ndarray:
    return functools.reduce(jnp.logical_and, [jnp.all(jnp.isfinite(a)) for a in arrays])


@float32_products
def solve(
    problem: PlanningProblem,
    key: jax.Array,
    config: PlannerConfig,
    prior: Prior,
    warm_start: jnp.ndarray | WarmStart | None = None,
    previous: PreviousPlan | None = None,
    safety_filter: SafetyFilter | None = None,
    unroll: bool = False,
) -> Solution:
    """The bi-level optimiser as a pure function; jit it with ``config`` and ``unroll`` static.

    problem: a checked PlanningProblem (planning frame, ego at x = 0). key: PRNG key.
    prior: first-iteration proposal (any pytree with ``propose``, :mod:`driveopt.priors`).
    warm_start: (8,) centre of the first proposal, a WarmStart, or None (the prior's ``default_mean``).
    previous: the previous replan's plan, or None (or its placeholder: ``PreviousPlan.absent``).
    safety_filter: pytree with ``initialise(problem, coeffs) -> FilterInit``, or None (the projection as configured).
    unroll: project with exactly ``projection.max_iterations`` steps (differentiable in reverse mode).
    No validation happens here: :func:`plan` checks its input first.
    """
    model = make_model(config.basis, config.qp)
    s = config.sampler
    key_prior, key_loop = jax.random.split(key)
    if isinstance(warm_start, WarmStart):
        warm_start = jnp.where(warm_start.present, warm_start.mean, default_mean(problem))
    proposal = prior.propose(problem, key_prior, s.num_samples, warm_start)

    def iteration(setpoints):
        return _iteration(model, problem, config, setpoints, previous, safety_filter, unroll)

    def adapt(mean, cov, snapshot, score):
        elites = snapshot.setpoints[snapshot.elite_index]
        return cem_update(mean, cov, elites, score[snapshot.elite_index], s)

    best, first, score, stats = iteration(proposal.samples)
    mean, cov = adapt(proposal.mean, proposal.cov, first, score)

    def body(carry, iteration_key):
        mean, cov, best, _ = carry
        setpoints = clip_setpoints(sample_gaussian(iteration_key, mean, cov, s.num_samples), problem, config.projection.v_max)
        cand, snapshot, score, stats = iteration(setpoints)
        best = _better(best, cand)
        mean, cov = adapt(mean, cov, snapshot, score)
        stats = stats._replace(best_score=best.score, best_feasible=best.feasible)
        return (mean, cov, best, snapshot), stats

    keys = jax.random.split(key_loop, s.num_iterations - 1)
    (mean, cov, best, last), rest = jax.lax.scan(body, (mean, cov, best, first), keys)
    history = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([jnp.atleast_1d(a), b]), stats, rest)
    status = jnp.where(
        ~_all_finite(best.coeffs, best.residuals, best.terms, mean),
        PlanStatus.NUMERICAL_ERROR,
        jnp.where(best.feasible, PlanStatus.SUCCESS, PlanStatus.INFEASIBLE),
    ).astype(jnp.int32)
    fallback, emergency, fallback_trajectory = _fallback(model, problem, config)
    return Solution(status, best, mean, cov, history, first, last, evaluate(model, best.coeffs), fallback,
                    fallback_trajectory, emergency)


@functools.cache
def compiled_solve():
    """:func:`solve`, jitted; on the CPU with the projection's compiler options (a per-jit setting)."""
    options = supported_compiler_options(XLA_CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else None
    return jax.jit(solve, static_argnames=("config", "unroll"), compiler_options=options)


_TRAJECTORY_KEYS = ("t", "x", "y", "speed", "heading", "curvature", "acceleration", "vx", "vy")


def _tolist(a: Any) -> Any:
    a = np.asarray(a)
    return (a.round(6) if np.issubdtype(a.dtype, np.floating) else a).tolist()


class PlanResult(NamedTuple):
    """What one planning call returns (numpy arrays, planning frame shifted back to the road frame)."""

    status: PlanStatus
    setpoints: np.ndarray  # (8,) chosen (v_1..v_4 [m/s], y_1..y_4 [m])
    coeffs: np.ndarray  # (2n,) chosen Bernstein coefficients (x in the planning frame, ego at x = 0)
    trajectory: Trajectory  # chosen trajectory in the road frame
    fallback: Trajectory  # stopping plan (comfortable, or emergency when it hits later), always finite
    costs: dict[str, float]  # weighted total under "total", plus every unweighted term
    residuals: dict[str, float]  # per family and "total"
    iterations: int  # sampler iterations run
    mean: np.ndarray  # (8,) final sampling mean: pass as warm_start to the next call
    history: History
    first: Snapshot
    last: Snapshot
    x_offset: float  # [m] road-frame x of the planning-frame origin
    fallback_residual: float  # total residual of the fallback
    fallback_deceleration: float  # [m/s^2] the fallback's braking: fallback_deceleration, or a_max (emergency)

    @property
    def message(self) -> str:
        return self.status.message

    @property
    def safe_trajectory(self) -> Trajectory:
        """The chosen trajectory when it is feasible, else the fallback.

        (Executing the less-violating of the two instead was tried in closed loop: it crashed
        four-lane-d3.0 seed 42 at 11.8 s, where always braking completed the episode.)"""
        return self.trajectory if self.status == PlanStatus.SUCCESS else self.fallback

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict: status, message, trajectory and fallback (arrays keyed t, x, y, speed, heading,
        curvature, acceleration, vx, vy), set-points, residuals, costs, iterations, history."""
        return {
            "status": self.status.name,
            "message": self.message,
            "trajectory": {k: _tolist(getattr(self.trajectory, k)) for k in _TRAJECTORY_KEYS},
            "fallback": {k: _tolist(getattr(self.fallback, k)) for k in _TRAJECTORY_KEYS},
            "setpoints": {"speed": _tolist(self.setpoints[:NUM_SEGMENTS]), "lateral": _tolist(self.setpoints[NUM_SEGMENTS:])},
            "residuals": self.residuals,
            "costs": self.costs,
            "iterations": self.iterations,
            "history": {k: _tolist(v) for k, v in self.history._asdict().items()},
        }


def plan(
    problem: PlanningProblem,
    config: PlannerConfig = PlannerConfig(),
    *,
    key: jax.Array,
    prior: Prior | None = None,
    warm_start: np.ndarray | WarmStart | None = None,
    previous: PreviousPlan | None = None,
    safety_filter: SafetyFilter | None = None,
    x_offset: float = 0.0,
) -> PlanResult:
    """Plan one trajectory. Raises ProblemError on malformed or non-finite input; never returns NaN.

    problem: from ``build_problem`` (planning frame, ego at x = 0).
    key: JAX PRNG key; split it between calls so that every call draws fresh samples.
    prior: first-iteration proposal distribution (default: GaussianPrior from ``config.sampler``).
    warm_start: (8,) mean from a previous result (``result.mean``) to centre the first proposal.
    previous: the previous replan's plan (``previous_plan``): a candidate row and the reference of the
        ``consistency`` cost term (weighted by ``config.cost.consistency``).
    A closed loop passes ``WarmStart.absent()`` and ``PreviousPlan.absent(num_nodes)`` on its first call instead of
    None: the result is the same, and every call of the loop runs one compiled function (a call with None and one
    with an array are two compilations).
    safety_filter: sets the projection's barrier parameters and initialisation (:mod:`driveopt.safety`).
    x_offset: [m] added to x of the returned trajectories (the ego's road-frame x).
    """
    check_problem(problem, config.basis)
    if prior is None:
        prior = GaussianPrior.from_config(config.sampler, config.projection.v_max)
    if warm_start is not None:
        warm_start = warm_start if isinstance(warm_start, WarmStart) else WarmStart(warm_start)
        mean = np.asarray(warm_start.mean, dtype=np.float32)
        if mean.shape != (SETPOINT_DIM,) or not np.all(np.isfinite(mean)):
            raise ProblemError(f"warm_start must be {SETPOINT_DIM} finite numbers, got shape {mean.shape}")
        warm_start = WarmStart(mean, _flag(warm_start.present, "warm_start.present"))
    placeholder = False
    if previous is not None:
        present = _flag(previous.present, "previous.present")
        previous = PreviousPlan(*(np.asarray(a, dtype=np.float32) for a in previous[:2]), present)
        shapes = (previous.setpoints.shape, previous.lateral.shape)
        if shapes != ((SETPOINT_DIM,), (config.basis.num_nodes,)) or not all(np.all(np.isfinite(a)) for a in previous[:2]):
            raise ProblemError(f"previous plan must be finite with shapes (8,) and ({config.basis.num_nodes},), got {shapes}")
        placeholder = not present
    solution = jax.device_get(compiled_solve()(problem, key, config, prior, warm_start, previous, safety_filter))
    if placeholder:  # the result as without a previous plan
        row = config.sampler.num_samples
        solution = solution._replace(first=_without_row(solution.first, row), last=_without_row(solution.last, row))
    return _to_result(solution, config, float(x_offset))


def _flag(value: Any, name: str) -> np.ndarray:
    """``value`` as a 0-d bool array (one compiled trace for Python and numpy booleans); ProblemError otherwise."""
    flag = np.asarray(value)
    if flag.shape != () or flag.dtype != np.bool_:
        raise ProblemError(f"{name} must be a boolean, got {value!r}")
    return flag


def _without_row(snapshot: Snapshot, row: int) -> Snapshot:
    """``snapshot`` with batch row ``row`` removed (a placeholder: never in the elite set) and the elite indices after it
    shifted down."""
    rows = {f: np.delete(getattr(snapshot, f), row, axis=0) for f in Snapshot._fields if f != "elite_index"}
    elite = np.asarray(snapshot.elite_index)
    return Snapshot(**rows, elite_index=np.where(elite > row, elite - 1, elite))


def _shift(traj: Trajectory, dx: float) -> Trajectory:
    return traj._replace(x=traj.x + dx)


def _to_result(solution: Solution, config: PlannerConfig, x_offset: float) -> PlanResult:
    """Numpy PlanResult in the road frame; on NUMERICAL_ERROR the fallback is reported as the choice."""
    status = PlanStatus(int(solution.status))
    fallback = _shift(solution.fallback_trajectory, x_offset)
    if status == PlanStatus.NUMERICAL_ERROR:
        chosen, trajectory, mean = solution.fallback, fallback, np.asarray(solution.fallback.setpoints)
    else:
        chosen, trajectory, mean = solution.best, _shift(solution.trajectory, x_offset), np.asarray(solution.mean)
    residuals = {f: float(v) for f, v in zip(FAMILIES, chosen.residuals)}
    residuals["total"] = float(sum(residuals.values()))
    return PlanResult(
        status=status,
        setpoints=np.asarray(chosen.setpoints),
        coeffs=np.asarray(chosen.coeffs),
        trajectory=trajectory,
        fallback=fallback,
        costs={"total": float(chosen.cost), **{k: float(v) for k, v in zip(COST_TERMS, chosen.terms)}},
        residuals=residuals,
        iterations=config.sampler.num_iterations,
        mean=mean,
        history=jax.tree_util.tree_map(np.asarray, solution.history),
        first=jax.tree_util.tree_map(np.asarray, solution.first),
        last=jax.tree_util.tree_map(np.asarray, solution.last),
        x_offset=x_offset,
        fallback_residual=float(np.sum(solution.fallback.residuals)),
        fallback_deceleration=config.projection.a_max if bool(solution.fallback_emergency) else config.fallback_deceleration,
    )
