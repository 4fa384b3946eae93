"""Registry of planners: the bi-level optimiser and the baselines of P1 §V, by name.

Every optimiser-based planner is a (PlannerConfig, prior) pair run by the same ``plan()``; the
``idm`` planner is highway-env's own IDM/MOBIL driver and is run by the simulator loop instead.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

from driveopt.baselines import GoalGridPrior, GridPrior, VanillaPrior
from driveopt.config import PlannerConfig
from driveopt.sampler import GaussianPrior


@dataclass(frozen=True)
class PlannerSpec:
    name: str
    description: str
    config: PlannerConfig = field(default_factory=PlannerConfig)
    make_prior: Callable[[PlannerConfig, int, str | None], Any] | None = None  # (config, lanes, weights); None: idm
    warm_start: bool = False  # carry the sampling mean between replans
    weights: str | None = None  # learned priors: checkpoint file (default: the weights shipped for the road)
    fixed_batch: bool = False  # the batch size is part of the method (vanilla: one sample); with_samples keeps it

    @property
    def is_optimiser(self) -> bool:
        return self.make_prior is not None

    def prior(self, lanes: int = 4) -> Any:
        """The first-iteration proposal for a road with ``lanes`` lanes (learned priors pick weights by it)."""
        if self.make_prior is None:
            raise ValueError(f"planner '{self.name}' does not use the optimiser")
        return self.make_prior(self.config, lanes, self.weights)

    def with_overrides(self, **sections: Any) -> "PlannerSpec":
        """Copy with config sections updated, e.g. ``sampler={"num_samples": 250}``."""
        return replace(self, config=self.config.replace(**sections))

    def with_samples(self, samples: int | None) -> "PlannerSpec":
        """Copy with ``samples`` per sampler iteration (elite counts capped at it); unchanged for ``None``,
        for ``idm`` and for planners whose batch size is part of the method (``fixed_batch``)."""
        if samples is None or not self.is_optimiser or self.fixed_batch:
            return self
        s = self.config.sampler
        elites = min(s.num_constraint_elites, samples)
        return self.with_overrides(
            sampler={"num_samples": samples, "num_constraint_elites": elites, "num_elites": min(s.num_elites, elites)}
        )

    def with_weights(self, weights: str | None) -> "PlannerSpec":
        """Copy that loads a learned prior from ``weights`` (a checkpoint file)."""
        return replace(self, weights=weights)


def _single_iteration(samples: int) -> dict:
    return {"num_samples": samples, "num_iterations": 1, "num_constraint_elites": min(100, samples), "num_elites": min(40, samples)}


def _gaussian(cfg: PlannerConfig, lanes: int = 4, weights: str | None = None) -> GaussianPrior:
    return GaussianPrior.from_config(cfg.sampler, cfg.projection.v_max)


def _cvae(gaussian_fraction: float) -> Callable[[PlannerConfig, int, str | None], Any]:
    def make(cfg: PlannerConfig, lanes: int, weights: str | None) -> Any:
        from driveopt.learned.prior import prior_for

        return prior_for(lanes, cfg.projection.v_max, weights, _gaussian(cfg), gaussian_fraction)

    return make


_BASE = PlannerConfig()
PLANNERS: dict[str, PlannerSpec] = {
    spec.name: spec
    for spec in (
        PlannerSpec("bilevel", "P1 bi-level optimiser: Gaussian start, 5 CEM iterations x 20 projection iterations",
                    _BASE, _gaussian, warm_start=True),
        PlannerSpec("bilevel-p1", "P1's Gaussian start exactly: independent set-points, no warm start (Fig. 9's baseline)",
                    _BASE.replace(sampler={"structured_fraction": 0.0}), _gaussian),
        PlannerSpec("cvae", "P1 bi-level optimiser started from the learned CVAE only (shipped weights; Gaussian if none)",
                    _BASE, _cvae(0.0)),
        PlannerSpec("cvae-mix", "bi-level optimiser: half the first batch from the CVAE, half from the bilevel Gaussian (warm start)",
                    _BASE, _cvae(0.5), warm_start=True),
        PlannerSpec("random", "one Gaussian draw of set-points, no adaptation (MPC-Random)",
                    _BASE.replace(sampler=_single_iteration(1000)), _gaussian),
        PlannerSpec("grid", "fixed grid: constant speed x target lane x change quarter (MPC-Grid)",
                    _BASE.replace(sampler=_single_iteration(320)), lambda c, *_: GridPrior(v_max=c.projection.v_max)),
        PlannerSpec("vanilla", "single speed set-point v_des in the current lane, no behavioural layer (MPC-Vanilla)",
                    _BASE.replace(sampler={"num_samples": 1, "num_iterations": 1, "num_constraint_elites": 1, "num_elites": 1},
                                  projection={"max_iterations": 100}),
                    lambda c, *_: VanillaPrior(v_max=c.projection.v_max), fixed_batch=True),
        PlannerSpec("batch", "goal positions (x_f, y_f) on a grid with terminal constraints (Batch-MPC)",
                    _BASE.replace(qp={"terminal_position": True}, sampler=_single_iteration(200)),
                    lambda c, *_: GoalGridPrior(v_max=c.projection.v_max)),
        PlannerSpec("idm", "highway-env's IDM/MOBIL driver on the ego (rule-based reference)"),
    )
}


def get_planner(name: str) -> PlannerSpec:
    """The registered planner ``name``; ValueError listing the valid names otherwise."""
    try:
        return PLANNERS[name]
    except KeyError:
        raise ValueError(f"unknown planner '{name}'; valid planners: {', '.join(PLANNERS)}") from None


def list_planners() -> list[str]:
    return list(PLANNERS)
