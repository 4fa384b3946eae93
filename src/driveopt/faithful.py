"""The papers' planners as the papers and their authors' public code ran them: driveopt's *faithful* planners.

driveopt's own planners (``bilevel``, ``grid``, ``vqvae-filter``, ...) carry its safety machinery; the faithful ones
(``*-faithful``) leave all of it out and take every number from the paper, or where the paper is silent from its
authors' public code: P1's ``MPC-Bi-Level`` (``main_bilevel.py``, ``main_baseline.py``, ``utils/env_config.py``,
``expert_mpc/``; its Batch-MPC expert, ``expert_mpc/expert_batch.py``, is published only in the same group's
``DiffProj``) and P2's ``VQOptMain`` (``inferenceJax3.py``, ``utils/config.py``, ``model/DOptimizerJax.py``).

Common to all of them (:func:`without_driveopt_machinery`: one ``dataclasses.replace`` of the spec's ``method``,
``loop`` and maths): the papers' method (:meth:`driveopt.method.Method.as_papers`: the paper's ranking, the residual
leading: P1's with its authors' driving cost, :class:`~driveopt.ranking.P1AuthorsRanking`; P2's and [5]'s
:class:`~driveopt.ranking.CostPlusResidual`; no stop rows; a fallback without straightening or sideways stops), the
papers' loop (:meth:`driveopt.drivers.optimiser.ClosedLoop.papers`: the chosen plan executed whatever its residual, the
fallback only on NUMERICAL_ERROR, no contact guard, constant-velocity prediction of the 10 nearest neighbours) with a
new plan every policy period (:data:`AUTHORS_REPLAN_EVERY`), and :data:`FAITHFUL_MATHS`, for the bi-level optimiser
and its baselines alike. MPC-Bi-Level carries its
sampling mean from call to call (``policy_bilevel.py``: ``self.mean_param``), the baselines do not. Both authors'
loops call the planner once per ``env.step`` for every method, at a 25 Hz policy over a 100 Hz simulation; P1
§V-A3's "first five elements" executed open loop are controls 0.01 s apart (the plan resampled at 1500 nodes over
15 s), so a plan lived 0.04-0.05 s. driveopt's scenarios step the policy at 10 Hz, so 0.1 s is the closest period.

What is not carried (driveopt shares it between all planners): the authors' projection penalty weights (P1's
baselines weigh the obstacle rows 100, its bi-level optimiser 1; ``projection.rho_obstacle`` could be set per planner,
but on driveopt's projection 100 does not carry the experts' balance: docs/design.md, Batch-MPC), Batch-MPC's guessed
projection starts (driveopt's projection starts from its target), acceleration bounds (driveopt caps every plan at
what the simulated car can do), P2's three circles per car, the car's lateral acceleration imposed at a plan's start
(:data:`FAITHFUL_MATHS`; P2's pipelines impose zero, as their authors do: :data:`P2_MATHS`), how P1's and [5]'s plans
become commands (P2's pipelines take their authors' command: :func:`p2_planner`), and the simulator: P2's authors ran
a highway-env copy with 4.0 x 1.4 m cars, a slip-free ego at a 25 Hz policy (docs/findings/p2-faithful-collisions.md
measures what each changes). docs/design.md lists every choice.
"""

from __future__ import annotations

import dataclasses

from driveopt.config import PlannerConfig
from driveopt.drivers.commands import P2_AUTHORS_COMMAND
from driveopt.drivers.optimiser import ClosedLoop, OptimiserSpec
from driveopt.priors.cvae import cvae_prior
from driveopt.priors.p1_authors import BatchGoals, FixedGaussian, LearnedStart, SpeedOffsetGrid, VanillaGuesses
from driveopt.qp import NUM_SEGMENTS
from driveopt.ranking import CostPlusResidual, P1AuthorsRanking, P2AuthorsRanking, Ranking

SUFFIX = "-faithful"
AUTHORS_REPLAN_EVERY = 1  # [policy periods] a new plan every period, for the optimiser and its baselines alike

P1_RANKING_COST_WEIGHT = 1e-5  # [-] the -p1 baselines' weight of driveopt's cost in P1's ranking: P1's authors' code
# ranks by residual + 1e-5 x the L2 norm of the speed error over the nodes (+ steering and heading terms, which the
# *-faithful planners carry: P1AuthorsRanking); on driveopt's cost scale (means of squares, ~100 for a 10 m/s speed
# error) 1e-5 gives the driving cost the same small share, so the residual leads.
P1_RANDOM_SPEED_WEIGHT = 1e-5  # [s/m] the authors' velocity_scaling: expert_random.py, expert_vanilla.py
P1_GRID_SPEED_WEIGHT = 1e-2  # [s/m] expert_grid.py
P1_BATCH_SPEED_WEIGHT = 1e-2  # [s/m] DiffProj's expert_mpc/expert_batch.py compute_cost (MPC-Bi-Level lacks the file)
P1_BILEVEL_SPEED_WEIGHT = 1e-3  # [s/m] expert_bilevel.py
SHRESTHA_COST_WEIGHT = 1e-3  # [-] [5]'s ranking: residual + 1e-3 x speed error (expert_cvae.py), on driveopt's cost

SHRESTHA_PROJECTION = 75  # [-] [5]'s planning projection iterations (main_diffproj.py --maxiter default; training unrolls 20)
SHRESTHA_CONSTRAINT_ELITES, SHRESTHA_ELITES = 10, 5  # [-] expert_cvae.py ellite_num_projection, ellite_num

P1_MATHS = {"sampler": {"structured_fraction": 0.0}, "qp": {"initial_lateral_acceleration": True},
            "cost": {"consistency": 0.0, "slowing": 0.0, "lane_flow": 0.0},
            "projection": {"course_max": 0.0, "ego_turn_rate": 0.0}}
# P1's planner maths where driveopt's differs: independent set-points, both initial accelerations imposed, no
# plan-consistency cost, v_des from a plan's first node, no lane-flow cost, no course bound or per-sample turned box.
FAITHFUL_MATHS = {**P1_MATHS, "qp": {"initial_lateral_acceleration": False}}
P2_FILTER_ITERATIONS = 100  # [-] the iterations of P2's filter in its one pass, unaccelerated
P2_MATHS = {**P1_MATHS, "qp": {"initial_lateral_acceleration": True},
            "projection": {**P1_MATHS["projection"], "max_iterations": P2_FILTER_ITERATIONS, "anderson_window": 0,
                           "derivative_bounds": "nodes"}}
# P2's pipelines: both initial accelerations imposed, at zero (P2_LOOP), as their authors' DOptimizerJax.py does, and
# their filter's iterations unaccelerated, its bounds at the nodes, as driveopt's vqvae and cvae-filter run them
# (driveopt.registry.P2_PASS_PROJECTION; vqvae-filter accelerates fewer: VQVAE_FILTER_PROJECTION)
# The *-faithful planners' maths: P1's, except that a plan's lateral acceleration at its start is left free as in
# driveopt's. Imposing the car's (the authors' code does, in a loop that replans every 0.04 s and tracks at 100 Hz)
# made every plan of driveopt's 10 Hz loop start with the turn the car was in: the faithful MPC-Bi-Level turned further
# each period and left a sparse four-lane road within 7 s, or collided (docs/findings/faithful-drift.md).

P1_SAMPLES = 1000  # [-] P1 §V-A1 and every expert of expert_mpc/ (num_batch); P1's protocols run the bi-level
# optimiser at 250 (§V-F)
P1_CONSTRAINT_ELITES, P1_ELITES = 150, 50  # [-] P1 §V-A1; also expert_grid.py and expert_random.py
P1_BILEVEL_ITERATIONS, P1_BILEVEL_PROJECTION = 5, 20  # [-] expert_bilevel.py maxiter_cem, maxiter
P1_BASELINE_PROJECTION = 100  # [-] expert_grid.py, expert_random.py, expert_vanilla.py maxiter (one CEM iteration)
P1_VANILLA_CONSTRAINT_ELITES = 300  # [-] expert_vanilla.py ellite_num_projection
P1_BATCH_CONSTRAINT_ELITES = 100  # [-] DiffProj's expert_batch.py ellite_num_projection (its ellite_num, 50, is unused:
# one CEM iteration, maxiter_cem = 1, picks the least cost among those)
P1_BATCH_QP = {"terminal_position": True, "terminal_longitudinal": False, "w_lateral": 0.0}  # expert_batch.py's QP:
# y(T) = y_f and y'(T) = 0 imposed, no x(T) row (A_eq_x: the initial state only), the goal speed tracked (rho_v = 1,
# k_p_v = 20, smoothness 0.1: driveopt's w_speed, k_pv, w_smooth), no lateral tracking term in the y-axis cost
P1_START_SPEED = 5.0  # [m/s] policy_bilevel.py: mean speed of the first call (a closed loop starts from the current one)
P1_START_SPEED_VAR = (30.0,) * NUM_SEGMENTS  # [(m/s)^2] policy_bilevel.py diag_param
P1_START_LATERAL_VAR = (30.0, 46.0, 46.0, 46.0)  # [m^2] policy_bilevel.py diag_param (the first offset's is 30)
P1_RANDOM_SPEED_VAR = (16.0,) * NUM_SEGMENTS  # [(m/s)^2] policy_random.py (mean v_des = 20)
P1_RANDOM_LATERAL_VAR = (46.0,) * NUM_SEGMENTS  # [m^2] policy_random.py


def without_driveopt_machinery(spec: OptimiserSpec, *, name: str, description: str, ranking: Ranking,
                               replan_every: int, maths: dict = P1_MATHS) -> OptimiserSpec:
    """``spec`` without driveopt's safety machinery: the papers' method with ``ranking`` (no stop rows, a fallback
    without straightening or sideways stops; its row sharing kept), the papers' loop (that fallback followed only on
    NUMERICAL_ERROR, no contact guard, constant-velocity prediction of the nearest neighbours) with a plan every
    ``replan_every`` policy periods, and ``maths`` (:data:`P1_MATHS`)."""
    return dataclasses.replace(spec, name=name, description=description, config=spec.config.replace(**maths),
                               method=spec.method.as_papers(ranking), loop=ClosedLoop.papers(replan_every))


def faithful_version(spec: OptimiserSpec, *, name: str, description: str, ranking: Ranking) -> OptimiserSpec:
    """``spec`` as its paper's authors ran it (:func:`without_driveopt_machinery` with the paper's ``ranking``, a plan
    every period and :data:`FAITHFUL_MATHS`), registered as ``name`` with ``description``."""
    return without_driveopt_machinery(spec, name=name, description=description, ranking=ranking,
                                      replan_every=AUTHORS_REPLAN_EVERY, maths=FAITHFUL_MATHS)


def _learned_start(start: FixedGaussian):
    """Prior factory: the shipped CVAE's samples with the authors' carried distribution (:class:`LearnedStart`)."""
    learned = cvae_prior(0.0)

    def make(config: PlannerConfig, lanes: int, weights: str | None) -> LearnedStart:
        return LearnedStart(learned(config, lanes, weights), dataclasses.replace(start, v_max=config.projection.v_max))

    return make


P1_METHODS = ("bilevel", "cvae", "random", "grid", "vanilla", "batch")  # P1's bi-level optimiser (Gaussian and CVAE
# start) and its four MPC baselines (P1 §V-A3), each with a faithful planner


def p1_planner(method: str, *, name: str, description: str) -> OptimiserSpec:
    """P1's ``method`` (one of :data:`P1_METHODS`) as its authors ran it: their samples, grids, guesses, iterations,
    elites and ranking (:class:`~driveopt.ranking.P1AuthorsRanking` with their speed weight), a plan every period."""
    base = PlannerConfig()
    bilevel = base.replace(sampler={"num_samples": P1_SAMPLES, "num_iterations": P1_BILEVEL_ITERATIONS,
                                    "num_constraint_elites": P1_CONSTRAINT_ELITES, "num_elites": P1_ELITES},
                           projection={"max_iterations": P1_BILEVEL_PROJECTION})
    single = base.replace(sampler={"num_samples": P1_SAMPLES, "num_iterations": 1,
                                   "num_constraint_elites": P1_CONSTRAINT_ELITES, "num_elites": P1_ELITES},
                          projection={"max_iterations": P1_BASELINE_PROJECTION})
    start = FixedGaussian(P1_START_SPEED, P1_START_SPEED_VAR, P1_START_LATERAL_VAR, follows_warm_start=True)
    methods = {  # method -> (configuration, prior factory, carries its mean, the authors' speed weight)
        "bilevel": (bilevel, lambda c, *_: dataclasses.replace(start, v_max=c.projection.v_max), True, P1_BILEVEL_SPEED_WEIGHT),
        "cvae": (bilevel, _learned_start(start), True, P1_BILEVEL_SPEED_WEIGHT),
        "random": (single, lambda c, *_: FixedGaussian(None, P1_RANDOM_SPEED_VAR, P1_RANDOM_LATERAL_VAR, c.projection.v_max),
                   False, P1_RANDOM_SPEED_WEIGHT),
        "grid": (single, lambda *_: SpeedOffsetGrid(), False, P1_GRID_SPEED_WEIGHT),
        "vanilla": (single.replace(sampler={"num_constraint_elites": P1_VANILLA_CONSTRAINT_ELITES}),
                    lambda c, *_: VanillaGuesses(horizon=c.basis.horizon, v_max=c.projection.v_max), False, P1_RANDOM_SPEED_WEIGHT),
        "batch": (single.replace(qp=P1_BATCH_QP, sampler={"num_constraint_elites": P1_BATCH_CONSTRAINT_ELITES}),
                  lambda *_: BatchGoals(), False, P1_BATCH_SPEED_WEIGHT),
    }
    config, make_prior, warm_start, speed_weight = methods[method]
    spec = OptimiserSpec(method, description, config, make_prior, warm_start=warm_start, learned_prior=method == "cvae")
    return faithful_version(spec, name=name, description=description, ranking=P1AuthorsRanking(speed_weight=speed_weight))


def p2_planner(spec: OptimiserSpec, *, name: str, description: str) -> OptimiserSpec:
    """P2's one-pass pipeline ``spec`` (vqvae, vqvae-filter, cvae-filter) as P2's authors ran it (VQOptMain's
    ``model/DOptimizerJax.py`` ``inference``): the 150 lowest residuals, the least of their cost (a progress term gated
    by exp(-2 residual), :class:`~driveopt.ranking.P2AuthorsRanking`) executed whatever its residual, every plan
    starting at zero acceleration, the command the mean speed and steering of the plan's first eight nodes passed to
    the simulator unscaled (:data:`~driveopt.drivers.commands.P2_AUTHORS_COMMAND`), no driveopt safety machinery, a
    plan every period."""
    papers = without_driveopt_machinery(spec, name=name, description=description, ranking=P2AuthorsRanking(),
                                        replan_every=AUTHORS_REPLAN_EVERY, maths=P2_MATHS)
    return dataclasses.replace(papers, loop=dataclasses.replace(papers.loop, command=P2_AUTHORS_COMMAND,
                                                                measured_start=False))


def shrestha_planner(spec: OptimiserSpec, *, name: str, description: str) -> OptimiserSpec:
    """``cvae-multipliers`` as [5]'s authors ran it (main_diffproj.py, expert_mpc/expert_cvae.py): the same samples
    and multipliers, the 10 lowest residuals ranked by residual + 1e-3 x speed error, executed whatever the residual,
    no driveopt safety machinery, a plan every 0.1 s."""
    return faithful_version(spec, name=name, description=description, ranking=CostPlusResidual(SHRESTHA_COST_WEIGHT))
