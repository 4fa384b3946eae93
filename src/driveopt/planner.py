"""One planning call: bi-level sampling optimiser (P1 Alg. 1) over set-point QP + batch projection.

    result = plan(problem, config, key=key)            # PlanResult
    result = plan(problem, config, key=key2, warm_start=result.mean)
    result = plan(problem, config, key=key3, previous=previous_plan(result, elapsed=0.1))

Per sampler iteration: draw set-points (the prior's proposal first, then the adapted Gaussian),
solve the set-point QP for the batch, project the batch onto the constraints, rank, and update the
Gaussian with P1 eq. 6 over the elite set. Ranking puts feasible samples (total residual within
``sampler.residual_tolerance``) first, by cost + residual; infeasible ones follow, by residual for
the constraint-elite set and by cost + residual within it, as in P1.

Two stopping plans ride in every batch and are ranked like any sample: a comfortable stop at
``fallback_deceleration`` easing to the nearest lane centre, and an emergency stop at
``projection.a_max`` holding the current lateral position. The chosen trajectory is the best
feasible candidate over all iterations. When there is none the status is INFEASIBLE, the
lowest-residual candidate is reported, and ``result.fallback`` offers the comfortable stop, or the
emergency stop when its residual is lower.

Given the previous replan's plan (``previous``), its set-points ride in every batch too, and the
``consistency`` cost term measures each sample's lateral deviation from that plan: between two
near-equal manoeuvres (pass left or right) the one already begun keeps winning.
"""

from __future__ import annotations

import enum
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from driveopt.config import PlannerConfig
from driveopt.costs import COST_TERMS, Trajectory, cost_terms, evaluate, nearest_lane_center, weighted_cost
from driveopt.problem import PlanningProblem, ProblemError, check_problem
from driveopt.projection import FAMILIES, XLA_CPU_COMPILER_OPTIONS, project, supported_compiler_options
from driveopt.qp import NUM_SEGMENTS, boundary_values, fit_positions, make_model, solve_setpoint_qp
from driveopt.sampler import GaussianPrior, Prior, cem_update, clip_setpoints, sample_gaussian, select_lowest

_INFEASIBLE_PENALTY = 1e6


class PlanStatus(enum.IntEnum):
    SUCCESS = 0
    INFEASIBLE = 1
    NUMERICAL_ERROR = 2

    @property
    def message(self) -> str:
        return {
            PlanStatus.SUCCESS: "a sampled trajectory meets every constraint within the residual tolerance",
            PlanStatus.INFEASIBLE: "no sampled trajectory met the residual tolerance; use result.fallback",
            PlanStatus.NUMERICAL_ERROR: "the optimiser produced non-finite values; use result.fallback",
        }[self]


class Snapshot(NamedTuple):
    """The whole batch of one sampler iteration (for plots and videos)."""

    setpoints: jnp.ndarray  # (B, 8)
    qp_coeffs: jnp.ndarray  # (B, 2n) set-point QP solutions
    projected_coeffs: jnp.ndarray  # (B, 2n) after projection
    residual: jnp.ndarray  # (B,) total residual after projection
    elite_index: jnp.ndarray  # (q,) indices of the elite set


class History(NamedTuple):
    """Per-iteration scalars, each (num_iterations,)."""

    best_score: jnp.ndarray  # cost + residual of the best feasible-first elite so far
    elite_cost: jnp.ndarray  # mean cost + residual over the elite set
    min_residual: jnp.ndarray  # smallest total residual in the batch
    median_residual: jnp.ndarray  # median total residual in the batch
    num_feasible: jnp.ndarray  # samples within the residual tolerance
    projection_iterations: jnp.ndarray


class PreviousPlan(NamedTuple):
    """The plan chosen by the previous replan, seen from this one."""

    setpoints: jnp.ndarray  # (8,) its set-points (re-solved from the current state as a candidate)
    lateral: jnp.ndarray  # (K,) [m] its lateral positions at this call's node times


def previous_plan(result: "PlanResult", elapsed: float) -> PreviousPlan:
    """The executed plan of ``result`` (``safe_trajectory``) shifted by ``elapsed`` [s] to the next call's
    nodes; held at its last value beyond the horizon."""
    traj = result.safe_trajectory
    t = np.asarray(traj.t)
    lateral = np.interp(t + elapsed, t, np.asarray(traj.y)).astype(np.float32)
    return PreviousPlan(np.asarray(result.setpoints, dtype=np.float32), lateral)


class _Best(NamedTuple):
    score: jnp.ndarray  # () feasibility-first key: cost + residual (+ penalty when infeasible)
    setpoints: jnp.ndarray  # (8,)
    coeffs: jnp.ndarray  # (2n,)
    residuals: jnp.ndarray  # (4,) per family
    terms: jnp.ndarray  # (len(COST_TERMS),)
    cost: jnp.ndarray  # () weighted cost


class _RawResult(NamedTuple):
    best: _Best
    mean: jnp.ndarray
    cov: jnp.ndarray
    history: History
    first: Snapshot
    last: Snapshot
    trajectory: Trajectory  # of the best coefficients (planning frame)
    fallback_trajectory: Trajectory
    fallback: _Best  # the stop offered as fallback (identical in every iteration)
    fallback_emergency: jnp.ndarray  # () bool: the fallback is the emergency stop


class PlanResult(NamedTuple):
    """What one planning call returns (numpy arrays, planning frame shifted back to the road frame)."""

    status: PlanStatus
    setpoints: np.ndarray  # (8,) chosen (v_1..v_4 [m/s], y_1..y_4 [m])
    coeffs: np.ndarray  # (2n,) chosen Bernstein coefficients (x in the planning frame, ego at x = 0)
    trajectory: Trajectory  # chosen trajectory in the road frame
    fallback: Trajectory  # stopping plan (comfortable, or emergency when less violating), always finite
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


def stop_setpoints(problem: PlanningProblem, horizon: float, decel: float, to_lane_centre: bool) -> jnp.ndarray:
    """(8,) set-points describing a stop: speed at each quarter's end, lateral target."""
    quarter = horizon / NUM_SEGMENTS
    ends = quarter * jnp.arange(1, NUM_SEGMENTS + 1, dtype=jnp.float32)
    speed = jnp.hypot(problem.init_x[1], problem.init_y[1])
    v = jnp.maximum(speed - decel * ends, 0.0)
    y = nearest_lane_center(problem, problem.init_y[0]) if to_lane_centre else problem.init_y[0]
    return jnp.concatenate([v, jnp.full(NUM_SEGMENTS, y)])


def goal_from_setpoints(setpoints: jnp.ndarray, init_x: jnp.ndarray, horizon: float) -> jnp.ndarray:
    """(B, 2) terminal goal (x_f, y_f) [m] implied by set-points: distance covered at the set speeds, last lateral."""
    quarter = horizon / NUM_SEGMENTS
    x_f = init_x[0] + quarter * jnp.sum(setpoints[:, :NUM_SEGMENTS], axis=1)
    return jnp.stack([x_f, setpoints[:, -1]], axis=1)


def _boundary(problem: PlanningProblem, cfg: PlannerConfig, setpoints: jnp.ndarray):
    """Equality right-hand sides; per sample when the QP imposes a terminal position (goal baseline)."""
    goal = goal_from_setpoints(setpoints, problem.init_x, cfg.basis.horizon) if cfg.qp.terminal_position else None
    return boundary_values(problem.init_x, problem.init_y, cfg.qp, goal)


def braking_coeffs(model, problem: PlanningProblem, decel: float, b_x, b_y, to_lane_centre: bool = True) -> jnp.ndarray:
    """(2n,) stop at constant deceleration ``decel`` [m/s^2], easing to the nearest lane centre in 3 s
    (or holding the current lateral position).

    A least-squares fit of that motion (the set-point QP's step set-points would overshoot it).
    """
    t = jnp.asarray(model.t)
    speed = jnp.hypot(problem.init_x[1], problem.init_y[1])
    moving = jnp.minimum(t, speed / decel)
    x = problem.init_x[0] + speed * moving - 0.5 * decel * moving**2
    centre = nearest_lane_center(problem, problem.init_y[0]) if to_lane_centre else problem.init_y[0]
    tau = jnp.minimum(t / 3.0, 1.0)
    y = problem.init_y[0] + (centre - problem.init_y[0]) * (3 * tau**2 - 2 * tau**3)
    return fit_positions(model, x, y, b_x, b_y)


def _iteration(model, problem, cfg: PlannerConfig, setpoints, previous: PreviousPlan | None):
    """QP + projection + ranking for one batch of set-points.

    Appended rows: the previous plan's set-points when given, then the comfortable fallback (brake
    at ``fallback_deceleration`` towards the nearest lane centre) and an emergency stop (brake at
    ``projection.a_max`` holding the current lateral position: a car straddling two lanes must not
    steer into the one it is about to hit); all are ranked like every sample.
    """
    s = cfg.sampler
    stops = ((cfg.fallback_deceleration, True), (cfg.projection.a_max, False))  # (decel [m/s^2], to lane centre)
    stop_rows = jnp.stack([stop_setpoints(problem, cfg.basis.horizon, *stop) for stop in stops])
    carried = [] if previous is None else [previous.setpoints[None]]
    setpoints = jnp.concatenate([setpoints, *carried, stop_rows])
    b_x, b_y = _boundary(problem, cfg, setpoints)
    qp_coeffs = solve_setpoint_qp(model, setpoints, b_x, b_y)
    row = (lambda b, i: b if b.ndim == 1 else b[i])  # noqa: E731  (boundary rows are per sample only for goals)
    for i, (decel, to_centre) in zip((-2, -1), stops):
        qp_coeffs = qp_coeffs.at[i].set(braking_coeffs(model, problem, decel, row(b_x, i), row(b_y, i), to_centre))
    proj = project(model, problem, qp_coeffs, b_x, b_y, cfg.projection)
    terms = cost_terms(evaluate(model, proj.coeffs), problem, None if previous is None else previous.lateral)
    cost = weighted_cost(terms, cfg.cost)
    residual = proj.residuals.total
    score = cost + residual
    feasible = residual <= s.residual_tolerance
    # ConstraintEliteSet: lowest residuals, where every feasible sample ties, so feasible samples come
    # first ordered by score, then infeasible ones by residual.
    key_score = jnp.where(feasible, score, _INFEASIBLE_PENALTY + residual)
    constraint_elites = select_lowest(key_score, s.num_constraint_elites)
    # EliteSet: lowest cost + residual of those (P1), feasible samples always ahead of infeasible ones.
    elite_key = jnp.where(feasible, score - _INFEASIBLE_PENALTY, score)
    ranked = constraint_elites[select_lowest(elite_key[constraint_elites], s.num_elites)]

    pick = ranked[jnp.argmin(key_score[ranked])]
    families = jnp.stack(list(proj.residuals))  # (4, rows)
    term_values = jnp.stack([terms[k] for k in COST_TERMS])  # (terms, rows)

    def candidate(i):
        return _Best(key_score[i], setpoints[i], proj.coeffs[i], families[:, i], term_values[:, i], cost[i])

    stats = (
        jnp.min(key_score[ranked]), jnp.mean(score[ranked]), jnp.min(residual), jnp.median(residual), jnp.sum(feasible),
        proj.iterations,
    )
    snapshot = Snapshot(setpoints, qp_coeffs, proj.coeffs, residual, ranked)
    # The fallback offered: the comfortable stop, unless the emergency stop has a lower residual.
    emergency = residual[-1] < residual[-2]
    fallback = jnp.where(emergency, residual.shape[0] - 1, residual.shape[0] - 2)
    return candidate(pick), (candidate(fallback), emergency), snapshot, score, stats


def _better(a: _Best, b: _Best) -> _Best:
    return jax.tree_util.tree_map(lambda u, v: jnp.where(a.score <= b.score, u, v), a, b)


def _plan_calls(problem: PlanningProblem, key: jax.Array, warm_mean, previous, prior, cfg: PlannerConfig) -> _RawResult:
    model = make_model(cfg.basis, cfg.qp)
    s = cfg.sampler
    key_prior, key_loop = jax.random.split(key)
    proposal = prior.propose(problem, key_prior, s.num_samples, warm_mean)

    def adapt(mean, cov, snapshot, score):
        elites = snapshot.setpoints[snapshot.elite_index]
        return cem_update(mean, cov, elites, score[snapshot.elite_index], s)

    best, (fallback, emergency), first, score, stats = _iteration(model, problem, cfg, proposal.samples, previous)
    mean, cov = adapt(proposal.mean, proposal.cov, first, score)

    def body(carry, iteration_key):
        mean, cov, best, _ = carry
        setpoints = clip_setpoints(sample_gaussian(iteration_key, mean, cov, s.num_samples), problem, cfg.projection.v_max)
        cand, _, snapshot, score, stats = _iteration(model, problem, cfg, setpoints, previous)
        best = _better(best, cand)
        mean, cov = adapt(mean, cov, snapshot, score)
        stats = (best.score,) + stats[1:]
        return (mean, cov, best, snapshot), stats

    keys = jax.random.split(key_loop, s.num_iterations - 1)
    (mean, cov, best, last), rest = jax.lax.scan(body, (mean, cov, best, first), keys)
    history = History(*(jnp.concatenate([jnp.atleast_1d(a), b]) for a, b in zip(stats, rest)))
    return _RawResult(best, mean, cov, history, first, last, evaluate(model, best.coeffs), evaluate(model, fallback.coeffs),
                      fallback, emergency)


@functools.cache
def _compiled_plan():
    """The jitted planning call; on the CPU with the projection's compiler options (a per-jit setting)."""
    options = supported_compiler_options(XLA_CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else None
    return jax.jit(_plan_calls, static_argnames=("cfg",), compiler_options=options)


def _shift(traj: Trajectory, dx: float) -> Trajectory:
    return traj._replace(x=traj.x + dx)


def plan(
    problem: PlanningProblem,
    config: PlannerConfig = PlannerConfig(),
    *,
    key: jax.Array,
    prior: Prior | None = None,
    warm_start: np.ndarray | None = None,
    previous: PreviousPlan | None = None,
    x_offset: float = 0.0,
) -> PlanResult:
    """Plan one trajectory. Raises ProblemError on malformed or non-finite input; never returns NaN.

    problem: from ``build_problem`` (planning frame, ego at x = 0).
    key: JAX PRNG key; split it between calls so that every call draws fresh samples.
    prior: first-iteration proposal distribution (default: GaussianPrior from ``config.sampler``).
    warm_start: (8,) mean from a previous result (``result.mean``) to centre the first proposal.
    previous: the previous replan's plan (``previous_plan``): a candidate row and the reference of the
        ``consistency`` cost term (weighted by ``config.cost.consistency``).
    x_offset: [m] added to x of the returned trajectories (the ego's road-frame x).
    """
    check_problem(problem, config.basis)
    if prior is None:
        prior = GaussianPrior.from_config(config.sampler, config.projection.v_max)
    if warm_start is not None:
        warm_start = np.asarray(warm_start, dtype=np.float32)
        if warm_start.shape != (2 * NUM_SEGMENTS,) or not np.all(np.isfinite(warm_start)):
            raise ProblemError(f"warm_start must be 8 finite numbers, got shape {warm_start.shape}")
        warm_start = jnp.asarray(warm_start)
    if previous is not None:
        previous = PreviousPlan(*(np.asarray(a, dtype=np.float32) for a in previous))
        shapes = (previous.setpoints.shape, previous.lateral.shape)
        if shapes != ((2 * NUM_SEGMENTS,), (config.basis.num_nodes,)) or not all(np.all(np.isfinite(a)) for a in previous):
            raise ProblemError(f"previous plan must be finite with shapes (8,) and ({config.basis.num_nodes},), got {shapes}")
    raw = jax.device_get(_compiled_plan()(problem, key, warm_start, previous, prior, config))
    return _finish(raw, problem, config, float(x_offset))


def _finish(raw: _RawResult, problem: PlanningProblem, config: PlannerConfig, x_offset: float) -> PlanResult:
    best = raw.best
    finite = all(np.all(np.isfinite(np.asarray(a))) for a in (best.coeffs, best.residuals, best.terms, raw.mean))
    if not finite:
        status = PlanStatus.NUMERICAL_ERROR
    elif best.score < _INFEASIBLE_PENALTY:
        status = PlanStatus.SUCCESS
    else:
        status = PlanStatus.INFEASIBLE
    fallback = _shift(raw.fallback_trajectory, x_offset)
    if status == PlanStatus.NUMERICAL_ERROR:  # report the fallback itself
        fb = raw.fallback
        setpoints = np.asarray(fb.setpoints)
        coeffs, trajectory, mean = np.asarray(fb.coeffs), fallback, setpoints
        chosen_residuals, chosen_terms, cost = fb.residuals, fb.terms, float(fb.cost)
    else:
        coeffs, setpoints, mean = np.asarray(best.coeffs), np.asarray(best.setpoints), np.asarray(raw.mean)
        trajectory = _shift(raw.trajectory, x_offset)

        chosen_residuals, chosen_terms, cost = best.residuals, best.terms, float(best.cost)
    residuals = {f: float(v) for f, v in zip(FAMILIES, chosen_residuals)}
    terms = {k: float(v) for k, v in zip(COST_TERMS, chosen_terms)}
    residuals["total"] = float(sum(residuals.values()))
    return PlanResult(
        status=status,
        setpoints=setpoints,
        coeffs=coeffs,
        trajectory=trajectory,
        fallback=fallback,
        costs={"total": cost, **terms},
        residuals=residuals,
        iterations=config.sampler.num_iterations,
        mean=mean,
        history=jax.tree_util.tree_map(np.asarray, raw.history),
        first=jax.tree_util.tree_map(np.asarray, raw.first),
        last=jax.tree_util.tree_map(np.asarray, raw.last),
        x_offset=x_offset,
        fallback_residual=float(np.sum(raw.fallback.residuals)),
        fallback_deceleration=config.projection.a_max if bool(raw.fallback_emergency) else config.fallback_deceleration,
    )
