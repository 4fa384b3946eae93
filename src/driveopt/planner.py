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
Gaussian with P1 eq. 6 over the elite set. The planner's ``method`` (:class:`driveopt.method.Method`, one frozen
dataclass passed as one static argument) decides what differs between driveopt's planner and the papers', with three
strategies: ``method.ranking`` (:mod:`driveopt.ranking`: feasible rows first, or P1's cost + residual),
``method.fallback`` (:class:`driveopt.fallback.Fallback`: the stops weighed when nothing is feasible and how one is
chosen, and with ``in_batch`` the comfortable and emergency stops ride in every batch, without it the samples alone)
and ``method.row_sharing`` (:mod:`driveopt.row_sharing`: whether a batch's repeated rows, a discrete prior's samples,
are projected once).

Rows appended to a batch (their :class:`RowKind` is in ``Snapshot.kind``) are ranked like any sample:
the previous replan's set-points when given, and the fallback's stops when ``in_batch``. The chosen trajectory is
the best candidate over all iterations by the ranking's key. The status is SUCCESS only when it is
feasible; otherwise it is INFEASIBLE, the chosen candidate is reported, and ``result.fallback`` offers
the stop that ``method.fallback`` chooses (computed whether or not the stops ride in the batch).

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

import enum
import functools
import math
import numbers
from typing import Any, Mapping, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from driveopt.config import PlannerConfig, check_planning_size, split_runtime, with_runtime
from driveopt.costs import COST_TERMS, cost_terms
from driveopt.fallback import Fallback, braking_coeffs, stop_setpoints
from driveopt.filtering import SafetyFilter, check_filter_init
from driveopt.host_copy import to_host
from driveopt.problem import PlanningProblem, check_problem
from driveopt.projection import FAMILIES, ProjectionResult, project
from driveopt.qp import NUM_SEGMENTS, SETPOINT_DIM, boundary_values, make_model, shift_setpoints, solve_setpoint_qp
from driveopt.method import DRIVEOPT_METHOD, Method
from driveopt.ranking import Candidate
from driveopt.row_sharing import EveryRow
from driveopt.sampler import GaussianPrior, Prior, cem_update, clip_setpoints, default_mean, sample_gaussian
from driveopt.scene import RANGES, ProblemError
from driveopt.solve_export import ExportedCalls
from driveopt.trajectory import Trajectory, evaluate
from driveopt.xla import XLA_CPU_COMPILER_OPTIONS, float32_products, supported_compiler_options


class PlanStatus(enum.IntEnum):
    """How a planning call ended; an int inside the compiled call (``Solution.status``), printed by name
    (``print(status)``, ``f"{status}"``: ``PlanStatus.SUCCESS``; ``int(status)`` and ``status.name`` as ever)."""

    SUCCESS = 0
    INFEASIBLE = 1
    NUMERICAL_ERROR = 2

    def __str__(self) -> str:
        return f"{type(self).__name__}.{self.name}"

    def __format__(self, spec: str) -> str:
        return format(str(self), spec)

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
    COMFORTABLE_STOP = 2  # brake at ``Fallback.deceleration`` towards the nearest lane centre
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
    first sample that is never ranked or counted, and the ``consistency`` term is zero, as without one."""

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
    nodes, held at its last value beyond the horizon; its set-points shifted as much (:func:`shift_setpoints`)."""
    traj = result.safe_trajectory
    t = np.asarray(traj.t)
    lateral = np.interp(t + elapsed, t, np.asarray(traj.y)).astype(np.float32)
    quarter = (t[-1] - t[0]) / NUM_SEGMENTS
    setpoints = shift_setpoints(np.asarray(result.setpoints, dtype=np.float32), elapsed / quarter)
    return PreviousPlan(setpoints, lateral, np.True_)


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
    return solve_setpoint_qp(model, setpoints, b_x, b_y), b_x, b_y


def project_batch(model, problem: PlanningProblem, cfg: PlannerConfig, qp_coeffs: jnp.ndarray, b_x, b_y,
                  safety_filter: SafetyFilter | None = None, unroll: bool = False,
                  iterations: jax.Array | None = None) -> ProjectionResult:
    """The projection of a batch of set-point-QP solutions (B, 2n) as the planner runs it: set up by
    ``safety_filter`` when given (FilterError for outputs of the wrong shape), as configured otherwise; with
    ``projection.max_iterations = 0`` the batch comes back unprojected and the filter is not consulted.
    iterations: a traced count of at most ``projection.max_iterations`` (None: that many)."""
    if safety_filter is None or cfg.projection.max_iterations == 0:
        return project(model, problem, qp_coeffs, b_x, b_y, cfg.projection, unroll=unroll, iterations=iterations)
    init = check_filter_init(safety_filter.initialise(problem, qp_coeffs), qp_coeffs.shape)
    return project(model, problem, qp_coeffs, b_x, b_y, cfg.projection, gamma_obs=init.gamma_obs, gamma_lane=init.gamma_lane,
                   init_coeffs=init.coeffs, init_multipliers=init.multipliers, unroll=unroll, iterations=iterations)


def _iteration(model, problem, cfg: PlannerConfig, setpoints, previous: PreviousPlan | None, safety_filter, unroll: bool,
               method: Method, iterations: jax.Array | None):
    """QP + projection + ranking for one batch of set-points (the appended rows: see the module docstring), projected
    with ``iterations`` (None: ``projection.max_iterations``).

    Returns (pick, snapshot, score, stats): the best row, the batch, every row's cost + residual, and
    the iteration's History entries.
    """
    s = cfg.sampler
    ranking = method.ranking
    stops = method.fallback.batch_stops(cfg.projection.a_max)
    num_samples = setpoints.shape[0]
    # An absent previous plan's row copies the first sample (the projection's batch-wide stop is unchanged) and is
    # excluded below wherever rows are ranked or counted.
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
    # Unrolled (to be differentiated) every row is projected: row sharing's loops run for a number of chunks that the
    # data decide, which reverse mode cannot differentiate; the rows' results are the same either way.
    sharing = EveryRow() if unroll else method.row_sharing
    def project_rows(c, bx, by):
        return project_batch(model, problem, cfg, c, bx, by, safety_filter, unroll, iterations)

    proj = sharing.project(project_rows, qp_coeffs, b_x, b_y)
    lateral = None if previous is None else previous.lateral

    traj = evaluate(model, proj.coeffs)
    # without a previous plan every row is its own reference: consistency exactly 0 (selecting the reference, not the
    # term, leaves the arithmetic of a present plan's term as it was)
    terms = cost_terms(traj, problem, lateral if previous is None else jnp.where(previous.present, lateral, traj.y),
                       cfg.cost.time_constant)
    cost = ranking.driving_cost(traj, problem, terms, cfg.cost)
    residual = proj.residuals.total
    score = ranking.score(cost, residual)
    feasible = residual <= s.residual_tolerance
    key_score = ranking.key(score, residual, feasible)
    if placeholder is not None:  # never ranked
        key_score, residual_key = jnp.where(placeholder, jnp.inf, key_score), jnp.where(placeholder, jnp.inf, residual)
        counted_feasible = feasible & ~placeholder
        # the median over the rows a call without the placeholder has
        median_residual = jnp.where(previous.present, jnp.median(residual), jnp.median(jnp.delete(residual, num_samples)))
    else:
        residual_key, counted_feasible, median_residual = residual, feasible, jnp.median(residual)
    ranked = ranking.elites(key_score, residual_key, score, feasible, s.num_constraint_elites, s.num_elites)

    pick = ranked[jnp.argmin(key_score[ranked])]
    families = jnp.stack(list(proj.residuals))  # (4, rows)
    term_values = jnp.stack([terms[k] for k in COST_TERMS])  # (terms, rows)

    def candidate(i):
        return Candidate(key_score[i], feasible[i], setpoints[i], proj.coeffs[i], families[:, i], term_values[:, i], cost[i])

    stats = History(
        best_score=key_score[pick], best_feasible=feasible[pick], elite_cost=jnp.mean(score[ranked]),
        min_residual=jnp.min(residual), median_residual=median_residual, num_feasible=jnp.sum(counted_feasible),
        projection_iterations=proj.iterations, projection_status=proj.status,
    )
    snapshot = Snapshot(setpoints, qp_coeffs, proj.coeffs, residual, ranked, kind, cost)
    return candidate(pick), snapshot, score, stats


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
    method: Method = DRIVEOPT_METHOD,
    runtime: Mapping[str, Mapping[str, jax.Array]] | None = None,
) -> Solution:
    """The bi-level optimiser as a pure function; jit it with ``config``, ``unroll`` and ``method`` static.

    problem: a checked PlanningProblem (planning frame, ego at x = 0). key: PRNG key.
    prior: first-iteration proposal (any pytree with ``propose``, :mod:`driveopt.priors`).
    warm_start: (8,) centre of the first proposal, a WarmStart, or None (the prior's ``default_mean``).
    previous: the previous replan's plan, or None (or its placeholder: ``PreviousPlan.absent``).
    safety_filter: pytree with ``initialise(problem, coeffs) -> FilterInit``, or None (the projection as configured).
    unroll: project with exactly ``projection.max_iterations`` steps (differentiable in reverse mode).
    method: how rows are ranked, which stops ride in every batch and are weighed as fallback, and whether repeated
    rows are projected once (:class:`driveopt.method.Method`; driveopt's by default).
    runtime: values of the configuration's runtime fields (:func:`driveopt.config.split_runtime`) that replace
    ``config``'s, as inputs of the compiled call, so that configurations that differ only in them share a compilation.
    No validation happens here: :func:`plan` checks its input first.
    """
    if runtime is not None:
        config = with_runtime(config, runtime)
    model = make_model(config.basis, config.qp)
    s = config.sampler
    key_prior, key_loop = jax.random.split(key)
    if isinstance(warm_start, WarmStart):
        warm_start = jnp.where(warm_start.present, warm_start.mean, default_mean(problem))
    proposal = prior.propose(problem, key_prior, s.num_samples, warm_start)

    def iteration(setpoints, last):
        """Every sampler iteration but the last projects with ``projection.earlier_iterations``."""
        early, full = config.projection.earlier_iterations, config.projection.max_iterations
        iterations = None if early == full else jnp.where(last, full, early)
        return _iteration(model, problem, config, setpoints, previous, safety_filter, unroll, method, iterations)

    def adapt(mean, cov, snapshot, score):
        elites = snapshot.setpoints[snapshot.elite_index]
        return cem_update(mean, cov, elites, score[snapshot.elite_index], s)

    best, first, score, stats = iteration(proposal.samples, s.num_iterations == 1)
    mean, cov = adapt(proposal.mean, proposal.cov, first, score)

    def body(carry, inputs):
        mean, cov, best, _ = carry
        iteration_key, index = inputs
        setpoints = clip_setpoints(sample_gaussian(iteration_key, mean, cov, s.num_samples), problem, config.projection.v_max)
        cand, snapshot, score, stats = iteration(setpoints, index == s.num_iterations - 2)
        best = _better(best, cand)
        mean, cov = adapt(mean, cov, snapshot, score)
        stats = stats._replace(best_score=best.score, best_feasible=best.feasible)
        return (mean, cov, best, snapshot), stats

    keys = jax.random.split(key_loop, s.num_iterations - 1)
    indices = jnp.arange(s.num_iterations - 1)
    (mean, cov, best, last), rest = jax.lax.scan(body, (mean, cov, best, first), (keys, indices))
    history = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([jnp.atleast_1d(a), b]), stats, rest)
    status = jnp.where(
        ~_all_finite(best.coeffs, best.residuals, best.terms, mean),
        PlanStatus.NUMERICAL_ERROR,
        jnp.where(best.feasible, PlanStatus.SUCCESS, PlanStatus.INFEASIBLE),
    ).astype(jnp.int32)
    offered, emergency, fallback_trajectory = method.fallback.choose(model, problem, config, method.ranking)
    return Solution(status, best, mean, cov, history, first, last, evaluate(model, best.coeffs), offered,
                    fallback_trajectory, emergency)


_STATIC = ("config", "unroll", "method")


def _jit_options() -> dict[str, Any]:
    """On the CPU, the projection's compiler options (a per-jit setting)."""
    return {"compiler_options": supported_compiler_options(XLA_CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else None}


@functools.cache
def exported_solve() -> ExportedCalls:
    """:func:`solve` as :func:`plan` runs it: jitted, through graphs exported to the compilation cache's folder, so
    that a later process skips tracing and lowering (:mod:`driveopt.solve_export`); static arguments by keyword."""
    return ExportedCalls(solve, _STATIC, _jit_options())


def compiled_solve():
    """:func:`solve`, jitted (the same jit that :func:`exported_solve` runs graphs it does not export with)."""
    return exported_solve().plain


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
    fallback_deceleration: float  # [m/s^2] the fallback's braking: Fallback.deceleration, or a_max (emergency)

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
    method: Method = DRIVEOPT_METHOD,
    x_offset: float = 0.0,
) -> PlanResult:
    """Plan one trajectory. Raises ProblemError on malformed or non-finite input, ConfigError for a call estimated above
    the compile, work or memory limits against its obstacles (:func:`driveopt.config.check_planning_size`, unless
    ``DRIVEOPT_ALLOW_LARGE=1``); never returns NaN.

    problem: from ``build_problem`` (planning frame, ego at x = 0).
    key: one JAX PRNG key (``jax.random.PRNGKey``: shape (2,) uint32, or a typed ``jax.random.key``); split it
        between calls so that every call draws fresh samples.
    prior: first-iteration proposal distribution (default: GaussianPrior from ``config.sampler``).
    warm_start: (8,) mean from a previous result (``result.mean``) to centre the first proposal, a ``WarmStart``, or
        None: the prior's own centre, run as ``WarmStart.absent()`` (the same result), so that calls with and without
        a warm start share one compilation.
    previous: the previous replan's plan (``previous_plan``): a candidate row and the reference of the
        ``consistency`` cost term (weighted by ``config.cost.consistency``). A closed loop passes
        ``PreviousPlan.absent(num_nodes)`` on its first call instead of None, so that every call of the loop runs one
        compiled function (the absent plan's placeholder row makes the batch one row longer, which can change the
        result's rounding: a call with None does not have it).
    safety_filter: sets the projection's barrier parameters and initialisation (:mod:`driveopt.safety`).
    method: the strategies of :func:`solve` (:class:`driveopt.method.Method`: driveopt's by default; the papers' rules
        swap the ranking and the fallback, P2's pipelines share repeated rows).
    x_offset: [m] added to x of the returned trajectories (the ego's road-frame x): a finite real number within the
        scene's position range (``driveopt.scene.RANGES["x"]``), as the command line's problem files require.
    """
    checked = check_call(problem, config, key, warm_start, previous, x_offset)
    if prior is None:
        prior = GaussianPrior.from_config(config.sampler, config.projection.v_max)
    compiled_config, runtime = split_runtime(config)
    solution = to_host(exported_solve()(checked.problem, checked.key, prior=prior, warm_start=checked.warm_start,
                                        previous=checked.previous, safety_filter=safety_filter, config=compiled_config,
                                        method=method, runtime=runtime))
    return solution_result(solution, config, method, checked)


class CheckedCall(NamedTuple):
    """The inputs of one planning call as :func:`plan` hands them to :func:`solve` (:func:`check_call`)."""

    problem: PlanningProblem
    key: jax.Array
    warm_start: WarmStart  # numpy float32 mean and a 0-d bool flag
    previous: PreviousPlan | None  # numpy float32 arrays and a 0-d bool flag, or None
    placeholder: bool  # ``previous`` is the absent plan's placeholder: its row is removed from the snapshots
    x_offset: float  # [m]


def check_call(problem: PlanningProblem, config: PlannerConfig, key: jax.Array,
               warm_start: np.ndarray | WarmStart | None = None, previous: PreviousPlan | None = None,
               x_offset: float = 0.0) -> CheckedCall:
    """The input of :func:`plan` checked and in the form :func:`solve` compiles once for (ProblemError, ConfigError:
    see :func:`plan`)."""
    check_problem(problem, config.basis)
    check_planning_size(config, int(np.shape(problem.obstacle_x)[0]))  # before anything is compiled
    _check_key(key)
    x_offset = _checked_x_offset(x_offset)
    if not isinstance(warm_start, WarmStart):
        warm_start = WarmStart.absent() if warm_start is None else WarmStart(warm_start)
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
    return CheckedCall(problem, key, warm_start, previous, placeholder, x_offset)


def solution_result(solution: Solution, config: PlannerConfig, method: Method, checked: CheckedCall) -> PlanResult:
    """The :class:`PlanResult` of ``solution`` (numpy, one call's), made from the inputs ``checked``."""
    if checked.placeholder:  # the result as without a previous plan
        row = config.sampler.num_samples
        solution = solution._replace(first=_without_row(solution.first, row), last=_without_row(solution.last, row))
    return _to_result(solution, config, method.fallback, checked.x_offset)


def _shown(value: Any) -> str:
    """A one-line, at most 60-character description of ``value`` for an error message."""
    text = " ".join(repr(value).split())
    return text if len(text) <= 60 else text[:57] + "..."


def _checked_x_offset(value: Any) -> float:
    """``value`` [m] as a float when it is a real number (a Python or numpy number, or a 0-d array of one; not a bool),
    finite and within the scene's position range (``RANGES["x"]``, where the float32 road-frame positions of a
    trajectory keep centimetres); ProblemError otherwise."""
    real = isinstance(value, numbers.Real) or (isinstance(value, (np.ndarray, jax.Array)) and np.ndim(value) == 0
                                                and np.asarray(value).dtype.kind in "iuf")
    if not real or isinstance(value, (bool, np.bool_)):
        raise ProblemError(f"x_offset must be a real number [m], got {_shown(value)}")
    try:
        offset = float(value)
    except OverflowError:  # an integer beyond float's range
        offset = math.inf if value > 0 else -math.inf
    if not math.isfinite(offset):
        raise ProblemError(f"x_offset must be finite, got {offset}")
    low, high, unit = RANGES["x"]
    if not low <= offset <= high:
        raise ProblemError(f"x_offset must be within [{low:g}, {high:g}] {unit}, got {offset:g}")
    return offset


def _check_key(key: Any) -> None:
    """ProblemError unless ``key`` is one JAX PRNG key: a typed key of shape () (``jax.random.key``) or a (2,) uint32
    array (``jax.random.PRNGKey``, numpy's copy of one too)."""
    if isinstance(key, jax.Array) and jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key):
        if key.shape != ():
            raise ProblemError(f"key must be one PRNG key, got a batch of shape {key.shape}: pass one of them")
        return
    if not (isinstance(key, (np.ndarray, jax.Array)) and key.shape == (2,) and key.dtype == np.uint32):
        described = f"{type(key).__name__} of shape {key.shape} and dtype {key.dtype}" if hasattr(key, "dtype") else _shown(key)
        raise ProblemError(f"key must be a JAX PRNG key (jax.random.PRNGKey(seed): shape (2,) uint32, or "
                           f"jax.random.key(seed)), got {described}")


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


def _to_result(solution: Solution, config: PlannerConfig, fallback: Fallback, x_offset: float) -> PlanResult:
    """Numpy PlanResult in the road frame; on NUMERICAL_ERROR the fallback is reported as the choice."""
    status = PlanStatus(int(solution.status))
    stop = _shift(solution.fallback_trajectory, x_offset)
    if status == PlanStatus.NUMERICAL_ERROR:
        chosen, trajectory, mean = solution.fallback, stop, np.asarray(solution.fallback.setpoints)
    else:
        chosen, trajectory, mean = solution.best, _shift(solution.trajectory, x_offset), np.asarray(solution.mean)
    residuals = {f: float(v) for f, v in zip(FAMILIES, chosen.residuals)}
    residuals["total"] = float(sum(residuals.values()))
    return PlanResult(
        status=status,
        setpoints=np.asarray(chosen.setpoints),
        coeffs=np.asarray(chosen.coeffs),
        trajectory=trajectory,
        fallback=stop,
        costs={"total": float(chosen.cost), **{k: float(v) for k, v in zip(COST_TERMS, chosen.terms)}},
        residuals=residuals,
        iterations=config.sampler.num_iterations,
        mean=mean,
        history=jax.tree_util.tree_map(np.asarray, solution.history),
        first=jax.tree_util.tree_map(np.asarray, solution.first),
        last=jax.tree_util.tree_map(np.asarray, solution.last),
        x_offset=x_offset,
        fallback_residual=float(np.sum(solution.fallback.residuals)),
        fallback_deceleration=fallback.braking(bool(solution.fallback_emergency), config.projection.a_max),
    )
