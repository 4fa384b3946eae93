"""Planner names -> driver specs: the bi-level optimiser, its baselines (P1 §V) and highway-env's IDM.

Every optimiser is an :class:`~driveopt.drivers.optimiser.OptimiserSpec` (a ``PlannerConfig`` and a
prior factory) run by the same ``plan()``; ``idm`` hands the ego to highway-env's IDM/MOBIL driver;
``dqn`` and ``ppo`` are P1's RL baselines (:mod:`driveopt.drivers.rl`: a learned policy, ``--weights``).
A new planner is one entry of :data:`PLANNERS`; ``driveopt plan``, ``drive``, ``bench`` and
``collect`` all look names up here. ``random-p1``, ``grid-p1``, ``vanilla-p1`` and ``batch-p1`` are driveopt's
MPC baselines without the machinery driveopt adds (:func:`_p1_faithful`), at driveopt's budgets, each plan executed
for five periods. The ``*-faithful`` planners (:mod:`driveopt.faithful`) are P1's and P2's planners as the papers and
their authors' code ran them: the authors' samples, grids, guesses, iterations and ranking, a plan every period.
"""

from __future__ import annotations

from driveopt import faithful
from driveopt.config import PlannerConfig
from driveopt.drivers.base import DriverSpec
from driveopt.drivers.idm import IDMSpec
from driveopt.drivers.optimiser import OptimiserSpec
from driveopt.drivers.rl import RLSpec
from driveopt.errors import UnknownNameError
from driveopt.faithful import P1_RANKING_COST_WEIGHT, without_driveopt_machinery
from driveopt.priors.cvae import cvae_prior
from driveopt.priors.cvae_multipliers import prior_for as cvae_multipliers_prior
from driveopt.priors.grids import GoalGridPrior, GridPrior, VanillaPrior
from driveopt.priors.vqvae import vqvae_prior
from driveopt.ranking import CostPlusResidual
from driveopt.method import Method
from driveopt.row_sharing import DistinctRows
from driveopt.safety.cvae_multipliers import filter_for as cvae_multipliers_filter


class UnknownPlannerError(UnknownNameError):
    """No planner of that name is registered."""


def _single_iteration(config: PlannerConfig, samples: int) -> PlannerConfig:
    return config.with_samples(samples).replace(sampler={"num_iterations": 1})


def _p1_faithful(spec: OptimiserSpec, p1_name: str) -> OptimiserSpec:
    """``spec`` (same prior, samples and iterations) without driveopt's machinery, as P1 describes its ``p1_name``:
    P1's ranking (:data:`P1_RANKING_COST_WEIGHT`), P1's batch (no stop rows), a fallback without straightening or
    sideways stops, no contact guard, :data:`P1_MATHS`, constant-velocity prediction of the nearest neighbours now,
    its plan executed feasible or not for five periods (0.5 s). Not the authors' runs: their samples, grids, guesses
    and iterations, and a plan every period, are the ``*-faithful`` planners' (:mod:`driveopt.faithful`)."""
    description = (f"P1-faithful {p1_name}: {spec.name} without feasibility-first ranking, stop rows, structured first "
                   "batch, free lateral start, plan consistency, course bound, per-sample turned box, brake-now fallback "
                   "(nor its straightening or sideways stops), contact guard, braking prediction or approach-ranked neighbours; 5 periods per plan")
    return without_driveopt_machinery(spec, name=f"{spec.name}-p1", description=description,
                                      ranking=CostPlusResidual(P1_RANKING_COST_WEIGHT), replan_every=5)


REALTIME_SAMPLES = 150  # [-] bilevel's samples per sampler iteration: its planning time in closed loop on the 2-core CPU
# machine (dense four-lane traffic, one process) is 60 ms median, 77 ms p95 at 150 samples, within the 0.1 s control
# period, and 107 / 129 ms at 250 (docs/results/speed.md); P1's batch of 1000 is `--samples 1000`.
_BASE = PlannerConfig()
_MPC_BASELINES = {  # P1 §V-A3's name -> driveopt's version
    "MPC-Random": OptimiserSpec("random", "one Gaussian draw of set-points, no adaptation (MPC-Random)", _single_iteration(_BASE, 1000)),
    "MPC-Grid": OptimiserSpec("grid", "fixed grid: constant speed x target lane x change quarter (MPC-Grid)",
                              _single_iteration(_BASE, 320), lambda c, *_: GridPrior(v_max=c.projection.v_max)),
    "MPC-Vanilla": OptimiserSpec("vanilla", "single speed set-point v_des (reached by at most 5 m/s per quarter of the "
                                            "horizon) in the current lane, no behavioural layer (MPC-Vanilla)",
                                 _single_iteration(_BASE, 1).replace(projection={"max_iterations": 100}),
                                 lambda c, *_: VanillaPrior(v_max=c.projection.v_max), fixed_batch=True),
    "Batch-MPC": OptimiserSpec("batch", "goal positions (x_f, y_f) on a grid with terminal constraints (Batch-MPC)",
                               _single_iteration(_BASE.replace(qp={"terminal_position": True}), 200),
                               lambda c, *_: GoalGridPrior(v_max=c.projection.v_max)),
}
_OPTIMISERS = (
    OptimiserSpec("bilevel", "P1 bi-level optimiser: Gaussian start, 150 samples x 5 CEM iterations x 20 projection iterations (real time on 2 CPU cores; P1: 1000 samples)",
                  _BASE.with_samples(REALTIME_SAMPLES), warm_start=True),
    OptimiserSpec("bilevel-p1", "P1's Gaussian start exactly: independent set-points, no warm start (Fig. 9's baseline)",
                  _BASE.replace(sampler={"structured_fraction": 0.0})),
    OptimiserSpec("cvae", "P1 bi-level optimiser started from the learned CVAE only (shipped weights; Gaussian if none)",
                  _BASE, cvae_prior(0.0)),
    OptimiserSpec("cvae-mix", "bi-level optimiser: half the first batch from the CVAE, half from the bilevel Gaussian (warm start)",
                  _BASE, cvae_prior(0.5), warm_start=True),
    OptimiserSpec("vqvae", "P2: 1000 PixelCNN/VQ-VAE samples, one pass of the barrier projection (100 iterations), "
                           "least-cost feasible (shipped weights; Gaussian if none)",
                  _BASE.replace(sampler={"num_iterations": 1, "num_constraint_elites": 150},
                                projection={"max_iterations": 100, "barrier": True}), vqvae_prior(), method=Method(row_sharing=DistinctRows())),
    OptimiserSpec("vqvae-filter", "P2's full pipeline: vqvae with the learned safety filter setting up the barrier projection "
                                  "(shipped weights; without filter weights the plain filter, without VQ-VAE weights the Gaussian)",
                  _BASE.replace(sampler={"num_iterations": 1, "num_constraint_elites": 150},
                                projection={"max_iterations": 100, "barrier": True}), vqvae_prior(), learned_filter=True,
                  method=Method(row_sharing=DistinctRows())),
    OptimiserSpec("vqvae-cem", "P1 bi-level optimiser started from PixelCNN/VQ-VAE samples (shipped weights; Gaussian if none)",
                  _BASE, vqvae_prior()),
    OptimiserSpec("cvae-filter", "P1's CVAE through P2's pipeline: 1000 CVAE samples through vqvae's one pass (barrier projection, 100 iterations), "
                                 "least-cost feasible; differs from vqvae only in the prior (shipped weights; Gaussian if none)",
                  _BASE.replace(sampler={"num_iterations": 1, "num_constraint_elites": 150},
                                projection={"max_iterations": 100, "barrier": True}), cvae_prior(0.0)),
    OptimiserSpec("cvae-multipliers", "P2's CVAE baseline as its reference [5] built it: 1000 CVAE samples of set-points, each "
                                      "projected (75 iterations) from the initial multipliers the model predicts for it, one pass "
                                      "(shipped four-lane weights, or --weights from `driveopt train cvae-multipliers`; Gaussian and zero multipliers if none)",
                  _BASE.replace(sampler={"num_iterations": 1, "num_constraint_elites": faithful.SHRESTHA_CONSTRAINT_ELITES,
                                         "num_elites": faithful.SHRESTHA_ELITES},
                                projection={"max_iterations": faithful.SHRESTHA_PROJECTION}),
                  cvae_multipliers_prior, make_filter=cvae_multipliers_filter),
    *_MPC_BASELINES.values(),
    *(_p1_faithful(spec, p1_name) for p1_name, spec in _MPC_BASELINES.items()),
)
_P2_PIPELINES = ("vqvae", "vqvae-filter", "cvae-filter")  # P2's one-pass pipelines, each with a faithful version
PLANNERS: dict[str, DriverSpec] = {
    spec.name: spec
    for spec in (
        *_OPTIMISERS,
        *faithful.p1_planners(_BASE),
        *(faithful.p2_planner(spec) for spec in _OPTIMISERS if spec.name in _P2_PIPELINES),
        *(faithful.shrestha_planner(spec) for spec in _OPTIMISERS if spec.name == "cvae-multipliers"),
        IDMSpec("idm", "highway-env's IDM/MOBIL driver on the ego (rule-based reference)"),
        RLSpec("dqn", "P1's DQN baseline: one of five behaviours every 1 s, tracked by upstream's set-point controller "
                      "(shipped policy for the road's lane count, or --weights)", algo="dqn"),
        RLSpec("ppo", "P1's PPO baseline: one of five behaviours every 1 s, tracked by upstream's set-point controller "
                      "(shipped policy for the road's lane count, or --weights)", algo="ppo"),
    )
}


def get_planner(name: str) -> DriverSpec:
    """The registered planner ``name``; UnknownPlannerError listing the valid names otherwise."""
    try:
        return PLANNERS[name]
    except KeyError:
        raise UnknownPlannerError(f"unknown planner '{name}'; valid planners: {', '.join(PLANNERS)}") from None


def list_planners() -> list[str]:
    return list(PLANNERS)


def get_optimiser(name: str) -> OptimiserSpec:
    """The registered optimiser ``name`` (a planner that runs ``plan()``); UnknownPlannerError otherwise."""
    spec = get_planner(name)
    if not isinstance(spec, OptimiserSpec):
        optimisers = [n for n, s in PLANNERS.items() if isinstance(s, OptimiserSpec)]
        raise UnknownPlannerError(f"planner '{name}' does not plan with the optimiser; optimisers: {', '.join(optimisers)}")
    return spec
