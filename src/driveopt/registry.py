"""Planner names -> driver specs, as a table: one row per planner (name, family, one-line description, factory).

Every optimiser is an :class:`~driveopt.drivers.optimiser.OptimiserSpec` (a ``PlannerConfig``, a prior factory, a
method and a closed loop) run by the same ``plan()``; ``idm`` hands the ego to highway-env's IDM/MOBIL driver;
``dqn`` and ``ppo`` are P1's RL baselines (:mod:`driveopt.drivers.rl`: a learned policy, ``--weights``). The
families (:data:`FAMILIES`): driveopt's planners; the MPC baselines of P1 §V-A3 (``random``, ``grid``, ``vanilla``,
``batch``) and their ``-p1`` versions without the machinery driveopt adds, at driveopt's budgets, each plan executed
for five periods (:func:`_p1_version`); the ``*-faithful`` planners (:mod:`driveopt.faithful`), P1's and P2's planners
as the papers and their authors' code ran them (the authors' samples, grids, guesses, iterations and ranking, a plan
every period); and the references.

A new planner is one row of :data:`PLANNER_ROWS`; ``driveopt plan``, ``drive``, ``bench`` and ``collect`` all look
names up here. A row's description is the one its spec carries; its factory builds the spec only when the planner is
asked for (:func:`get_planner`, cached), importing what it needs then, so this module, and ``driveopt planners``
which lists the rows, load neither JAX nor Flax nor the simulator.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Callable, NamedTuple

from driveopt.errors import UnknownNameError

if TYPE_CHECKING:
    from driveopt.drivers.base import DriverSpec
    from driveopt.drivers.optimiser import OptimiserSpec


class UnknownPlannerError(UnknownNameError):
    """No planner of that name is registered."""


DRIVEOPT, MPC, FAITHFUL, REFERENCE = "driveopt", "mpc", "faithful", "reference"
FAMILIES: dict[str, str] = {  # family -> its heading in ``driveopt planners``, in listing order
    DRIVEOPT: "driveopt's planners",
    MPC: "MPC baselines (P1 §V-A3) and their P1-faithful versions (-p1)",
    FAITHFUL: "the papers' planners as their authors ran them (-faithful)",
    REFERENCE: "references (rule-based driver, P1's RL baselines)",
}


class PlannerRow(NamedTuple):
    """One registered planner: its name, family (:data:`FAMILIES`), one-line description, and the factory that builds
    its spec (no arguments; the spec's ``name`` and ``description`` are the row's)."""

    name: str
    family: str
    description: str
    factory: Callable[[], "DriverSpec"]


def _row(name: str, family: str, description: str, build: Callable[[str, str], "DriverSpec"]) -> PlannerRow:
    """A row whose factory is ``build(name, description)``."""
    return PlannerRow(name, family, description, functools.partial(build, name, description))


REALTIME_SAMPLES = 250  # [-] bilevel's samples per sampler iteration, the results tables' count: with its real-time
# projection it plans in 13.4 ms median, 15.3 ms p95 in closed loop on the 2-core CPU (dense four-lane traffic, its AMD
# EPYC variant; on the slower variants about 65-75 ms p95 is estimated, not measured), within the 0.1 s control period,
# and drove as safely and within 2 % as quickly as at 150 in paired episodes
# (docs/results/speed.md#the-real-time-default); P1's batch of 1000 is `--samples 1000`.
REALTIME_PROJECTION = {"max_iterations": 12, "anderson_window": 4, "derivative_bounds": "control_points",
                       "acceleration_recovery": True, "early_iterations": 7}  # bilevel's projection: 12 iterations [-]
# accelerated over a window of 4 [-], the speed and acceleration bounds at the control points of 4 pieces
# (projection.derivative_pieces), and 7 iterations [-] in every sampler iteration but the last; 2.7x fewer operations
# than 20 plain iterations at 250 x 5, and in closed loop as safe and within 2 % as quick
# (docs/results/speed.md#the-real-time-projection); the acceleration bound recovers from a car braking beyond it on a
# bend as the other bounds do (docs/controller.md)

P2_PASS_PROJECTION = {"max_iterations": 100, "anderson_window": 0, "derivative_bounds": "nodes"}  # the filter pass
# driveopt's P2 pipelines share in P2's comparisons: P2's 100 plain iterations [-] at the nodes; vqvae and cvae-filter
# run it, and every P2 arm of `driveopt reproduce` is pinned to it (driveopt.experiments.protocols), so that the
# pipelines compared still differ only in the prior or the filter; the *-faithful pipelines keep P2's
# (driveopt.faithful.P2_MATHS)
VQVAE_FILTER_PROJECTION = {"max_iterations": 60, "anderson_window": 4, "derivative_bounds": "control_points"}
# vqvae-filter's own pass: 60 iterations [-] accelerated over a window of 4 [-], the speed and acceleration bounds at
# the control points; 22-27 % less time per call than P2's pass, and in closed loop as safe and within 2 % as quick on
# the P1 roads and highway-v0 (docs/results/speed.md#p2s-one-pass-accelerated). The same pass failed vqvae's
# two-lane-d2.5 (2.8 % slower) and 50 accelerated iterations cvae-filter's highway-v0, so those two keep P2's pass.


# The factories: each imports what its spec needs when it is built.

def _optimiser(name: str, description: str, config, make_prior=None, **fields) -> "OptimiserSpec":
    from driveopt.drivers.optimiser import OptimiserSpec

    return OptimiserSpec(name, description, config, make_prior, **fields)


def _config(**sections):
    """driveopt's configuration with ``sections`` replaced."""
    from driveopt.config import PlannerConfig

    return PlannerConfig().replace(**sections)


def _single_iteration(samples: int, **sections):
    """driveopt's configuration at ``samples`` samples and one sampler iteration (``sections`` replaced first)."""
    return _config(**sections).with_samples(samples).replace(sampler={"num_iterations": 1})


def _p2_pass(projection: dict = P2_PASS_PROJECTION):
    """P2's one pass: 1000 samples, the 150 lowest residuals, the barrier projection (``projection``'s fields)."""
    return _config(sampler={"num_iterations": 1, "num_constraint_elites": 150}, projection={**projection, "barrier": True})


def _distinct_rows():
    """driveopt's method projecting each distinct row once (a discrete prior's repeated samples)."""
    from driveopt.method import Method
    from driveopt.row_sharing import DistinctRows

    return Method(row_sharing=DistinctRows())


def _learned_prior(kind: str, *options):
    """The prior factory, ``(config, lanes, weights) -> prior``, of the learned ``kind``'s row in
    :data:`driveopt.learned_kinds.KINDS`, made with ``options`` (the CVAE's: the share of its samples)."""
    from driveopt.learned_kinds import kind as learned_kind, resolve

    return resolve(learned_kind(kind).prior_factory)(*options)


def _bilevel(name: str, description: str):
    from driveopt.config import PlannerConfig

    config = PlannerConfig().with_samples(REALTIME_SAMPLES).replace(projection=REALTIME_PROJECTION)
    return _optimiser(name, description, config, warm_start=True)


def _bilevel_p1(name: str, description: str):
    return _optimiser(name, description, _config(sampler={"structured_fraction": 0.0}))


def _cvae(mix: float, warm_start: bool):
    def build(name: str, description: str):
        return _optimiser(name, description, _config(), _learned_prior("cvae", mix), warm_start=warm_start,
                          learned_prior=True)

    return build


def _vqvae(name: str, description: str):
    return _optimiser(name, description, _p2_pass(), _learned_prior("vqvae"), method=_distinct_rows(),
                      learned_prior=True)


def _vqvae_filter(name: str, description: str):
    return _optimiser(name, description, _p2_pass(VQVAE_FILTER_PROJECTION), _learned_prior("vqvae"), learned_filter=True,
                      method=_distinct_rows(), learned_prior=True)


def _vqvae_cem(name: str, description: str):
    return _optimiser(name, description, _config(), _learned_prior("vqvae"), learned_prior=True)


def _cvae_filter(name: str, description: str):
    return _optimiser(name, description, _p2_pass(), _learned_prior("cvae", 0.0), learned_prior=True)


def _cvae_multipliers(name: str, description: str):
    from driveopt import faithful
    from driveopt.learned_kinds import kind, resolve

    config = _config(sampler={"num_iterations": 1, "num_constraint_elites": faithful.SHRESTHA_CONSTRAINT_ELITES,
                              "num_elites": faithful.SHRESTHA_ELITES},
                     projection={"max_iterations": faithful.SHRESTHA_PROJECTION})
    return _optimiser(name, description, config, _learned_prior("cvae-multipliers"),
                      make_filter=resolve(kind("cvae-multipliers").filter_factory), learned_prior=True)


def _random(name: str, description: str):
    return _optimiser(name, description, _single_iteration(1000))


def _grid(name: str, description: str):
    from driveopt.priors.grids import GridPrior

    return _optimiser(name, description, _single_iteration(320), lambda c, *_: GridPrior(v_max=c.projection.v_max))


def _vanilla(name: str, description: str):
    from driveopt.priors.grids import VanillaPrior

    return _optimiser(name, description, _single_iteration(1).replace(projection={"max_iterations": 100}),
                      lambda c, *_: VanillaPrior(v_max=c.projection.v_max), fixed_batch=True)


def _batch(name: str, description: str):
    from driveopt.priors.grids import GoalGridPrior

    return _optimiser(name, description, _single_iteration(200, qp={"terminal_position": True}),
                      lambda c, *_: GoalGridPrior(v_max=c.projection.v_max))


def _p1_version(base: str):
    """Factory of ``base`` (same prior, samples and iterations) without driveopt's machinery, as P1 describes it: P1's
    ranking (:data:`driveopt.faithful.P1_RANKING_COST_WEIGHT`), P1's batch (no stop rows), a fallback without
    straightening or sideways stops, no contact guard, :data:`driveopt.faithful.P1_MATHS`, constant-velocity
    prediction of the nearest neighbours now, its plan executed feasible or not for five periods (0.5 s). Not the
    authors' runs: their samples, grids, guesses and iterations, and a plan every period, are the ``*-faithful``
    planners' (:mod:`driveopt.faithful`)."""

    def build(name: str, description: str):
        from driveopt.faithful import P1_RANKING_COST_WEIGHT, without_driveopt_machinery
        from driveopt.ranking import CostPlusResidual

        return without_driveopt_machinery(get_optimiser(base), name=name, description=description,
                                          ranking=CostPlusResidual(P1_RANKING_COST_WEIGHT), replan_every=5)

    return build


def _p1_faithful(method: str):
    def build(name: str, description: str):
        from driveopt.faithful import p1_planner

        return p1_planner(method, name=name, description=description)

    return build


def _p2_faithful(base: str):
    def build(name: str, description: str):
        from driveopt.faithful import p2_planner

        return p2_planner(get_optimiser(base), name=name, description=description)

    return build


def _shrestha_faithful(name: str, description: str):
    from driveopt.faithful import shrestha_planner

    return shrestha_planner(get_optimiser("cvae-multipliers"), name=name, description=description)


def _idm(name: str, description: str):
    from driveopt.drivers.idm import IDMSpec

    return IDMSpec(name, description)


def _rl(algo: str):
    def build(name: str, description: str):
        from driveopt.drivers.rl import RLSpec

        return RLSpec(name, description, algo=algo)

    return build


def _p1_description(base: str, p1_name: str) -> str:
    return (f"P1-faithful {p1_name}: {base} without feasibility-first ranking, stop rows, structured first batch, free "
            "lateral start, plan consistency, course bound, per-sample turned box, brake-now fallback (nor its "
            "straightening or sideways stops), contact guard, braking prediction or approach-ranked neighbours; "
            "5 periods per plan")


_AUTHORS_P1 = "P1's ranking and its authors' cost, no driveopt safety machinery, a plan every 0.1 s"


def _p2_description(base: str) -> str:
    return (f"{base} as P2's authors ran it (inferenceJax3.py, DOptimizerJax.py): the same samples, prior and filter, "
            "the least of their gated progress cost + residual of the 150 lowest residuals executed whatever its "
            "residual, plans from zero acceleration, their command (the first 8 nodes' mean speed and steering), no "
            "driveopt safety machinery, a plan every 0.1 s")


_RL = ("one of five behaviours every 1 s, tracked by upstream's set-point controller (shipped policy for the road's "
       "lane count, or --weights)")

PLANNER_ROWS: tuple[PlannerRow, ...] = (
    _row("bilevel", DRIVEOPT, "P1 bi-level optimiser: Gaussian start, 250 samples x 5 CEM iterations x 12 accelerated "
         "projection iterations, 7 before the last CEM iteration (real time on 2 CPU cores; P1: 1000 samples x 20 "
         "iterations)", _bilevel),
    _row("bilevel-p1", DRIVEOPT, "P1's Gaussian start exactly: independent set-points, no warm start (Fig. 9's baseline)",
         _bilevel_p1),
    _row("cvae", DRIVEOPT, "P1 bi-level optimiser started from the learned CVAE only (shipped weights; Gaussian if none)",
         _cvae(0.0, warm_start=False)),
    _row("cvae-mix", DRIVEOPT, "bi-level optimiser: half the first batch from the CVAE, half from the bilevel Gaussian "
         "(warm start)", _cvae(0.5, warm_start=True)),
    _row("vqvae", DRIVEOPT, "P2: 1000 PixelCNN/VQ-VAE samples, one pass of the barrier projection (100 iterations), "
         "least-cost feasible (shipped weights; Gaussian if none)", _vqvae),
    _row("vqvae-filter", DRIVEOPT, "P2's full pipeline: vqvae with the learned safety filter setting up the barrier "
         "projection, 60 accelerated iterations (shipped weights; without filter weights the plain filter, without "
         "VQ-VAE weights the Gaussian)",
         _vqvae_filter),
    _row("vqvae-cem", DRIVEOPT, "P1 bi-level optimiser started from PixelCNN/VQ-VAE samples (shipped weights; Gaussian "
         "if none)", _vqvae_cem),
    _row("cvae-filter", DRIVEOPT, "P1's CVAE through P2's pipeline: 1000 CVAE samples through vqvae's one pass (barrier "
         "projection, 100 iterations), least-cost feasible; differs from vqvae only in the prior (shipped weights; "
         "Gaussian if none)", _cvae_filter),
    _row("cvae-multipliers", DRIVEOPT, "P2's CVAE baseline as its reference [5] built it: 1000 CVAE samples of "
         "set-points, each projected (75 iterations) from the initial multipliers the model predicts for it, one pass "
         "(shipped four-lane weights, or --weights from `driveopt train cvae-multipliers`; Gaussian and zero "
         "multipliers if none)", _cvae_multipliers),
    _row("random", MPC, "one Gaussian draw of set-points, no adaptation (MPC-Random)", _random),
    _row("grid", MPC, "fixed grid: constant speed x target lane x change quarter (MPC-Grid)", _grid),
    _row("vanilla", MPC, "single speed set-point v_des (reached by at most 5 m/s per quarter of the horizon) in the "
         "current lane, no behavioural layer (MPC-Vanilla)", _vanilla),
    _row("batch", MPC, "goal positions (x_f, y_f) on a grid with terminal constraints (Batch-MPC)", _batch),
    _row("random-p1", MPC, _p1_description("random", "MPC-Random"), _p1_version("random")),
    _row("grid-p1", MPC, _p1_description("grid", "MPC-Grid"), _p1_version("grid")),
    _row("vanilla-p1", MPC, _p1_description("vanilla", "MPC-Vanilla"), _p1_version("vanilla")),
    _row("batch-p1", MPC, _p1_description("batch", "Batch-MPC"), _p1_version("batch")),
    _row("bilevel-faithful", FAITHFUL, "P1 Alg. 1 as P1's authors ran it: 1000 samples from N(m, diag(30, 46)), m the "
         "previous call's final mean (before the first call the current motion), 5 CEM iterations x 20 projection "
         f"iterations, elites 150 -> 50; {_AUTHORS_P1}", _p1_faithful("bilevel")),
    _row("cvae-faithful", FAITHFUL, "P1's MPC-Bi-Level as its authors' main_bilevel.py ran it: bilevel-faithful with the "
         f"learned CVAE's samples as its first batch (shipped weights; Gaussian if none); {_AUTHORS_P1}",
         _p1_faithful("cvae")),
    _row("random-faithful", FAITHFUL, "MPC-Random as P1's authors ran it: 1000 samples from N((v_des, y0), diag(16, "
         f"46)), one pass of 100 projection iterations, elites 150; {_AUTHORS_P1}", _p1_faithful("random")),
    _row("grid-faithful", FAITHFUL, "MPC-Grid as P1's authors ran it: 50 speeds on v_des +- 16 m/s x 20 offsets across "
         f"the road, held over the horizon, one pass of 100 projection iterations, elites 150; {_AUTHORS_P1}",
         _p1_faithful("grid")),
    _row("vanilla-faithful", FAITHFUL, "MPC-Vanilla as P1's authors ran it: speed set-point v_des, 1000 lateral guesses "
         "(the least obstructed of 30000 smooth paths), one pass of 100 projection iterations, elites 300; "
         f"{_AUTHORS_P1}", _p1_faithful("vanilla")),
    _row("batch-faithful", FAITHFUL, "Batch-MPC as its authors' expert_batch.py (published in DiffProj) ran it: 1000 "
         "goals, 25 speeds on v_des +- 12 m/s tracked x 40 terminal lateral positions y(T) = y_f across the road (no "
         f"x(T) constraint, no lateral tracking), one pass of 100 projection iterations, elites 100; {_AUTHORS_P1}",
         _p1_faithful("batch")),
    _row("vqvae-faithful", FAITHFUL, _p2_description("vqvae"), _p2_faithful("vqvae")),
    _row("vqvae-filter-faithful", FAITHFUL, _p2_description("vqvae-filter"), _p2_faithful("vqvae-filter")),
    _row("cvae-filter-faithful", FAITHFUL, _p2_description("cvae-filter"), _p2_faithful("cvae-filter")),
    _row("cvae-multipliers-faithful", FAITHFUL, "cvae-multipliers as [5]'s authors ran it (main_diffproj.py): the same "
         "samples and multipliers, the least residual + 1e-3 speed error of the 10 lowest residuals executed whatever "
         "its residual, no driveopt safety machinery, a plan every 0.1 s", _shrestha_faithful),
    _row("idm", REFERENCE, "highway-env's IDM/MOBIL driver on the ego (rule-based reference)", _idm),
    _row("dqn", REFERENCE, f"P1's DQN baseline: {_RL}", _rl("dqn")),
    _row("ppo", REFERENCE, f"P1's PPO baseline: {_RL}", _rl("ppo")),
)
_ROWS = {row.name: row for row in PLANNER_ROWS}


def planner_rows(family: str | None = None) -> tuple[PlannerRow, ...]:
    """The registered planners' rows in registration order (of ``family`` only, when given); nothing is built."""
    return tuple(row for row in PLANNER_ROWS if family is None or row.family == family)


def list_planners() -> list[str]:
    """The registered planners' names, in registration order."""
    return list(_ROWS)


def _row_of(name: str) -> PlannerRow:
    try:
        return _ROWS[name]
    except KeyError:
        raise UnknownPlannerError(f"unknown planner '{name}'; valid planners: {', '.join(_ROWS)}") from None


@functools.cache
def _built(name: str) -> "DriverSpec":
    return _ROWS[name].factory()


def get_planner(name: str) -> "DriverSpec":
    """The registered planner ``name``, built by its row's factory on the first request and the same object after;
    UnknownPlannerError listing the valid names otherwise."""
    return _built(_row_of(name).name)


def get_optimiser(name: str) -> "OptimiserSpec":
    """The registered optimiser ``name`` (a planner that runs ``plan()``: every family's but the references');
    UnknownPlannerError otherwise."""
    if _row_of(name).family == REFERENCE:
        optimisers = [row.name for row in PLANNER_ROWS if row.family != REFERENCE]
        raise UnknownPlannerError(f"planner '{name}' does not plan with the optimiser; optimisers: {', '.join(optimisers)}")
    return get_planner(name)
