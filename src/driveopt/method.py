"""The planner's method: how a batch is ranked, what rides in it and what is offered when nothing is feasible, and
whether its repeated rows are projected once, as one value.

    from driveopt.method import DRIVEOPT_METHOD, Method, papers_method
    plan(problem, config, key=key, method=Method(ranking=CostPlusResidual(1e-5)))

The configuration (:class:`driveopt.config.PlannerConfig`) is the maths every method shares; a :class:`Method` says
where driveopt's planner and the papers' differ in the rules, with three strategies:

- ``ranking`` (:mod:`driveopt.ranking`): driveopt's :class:`~driveopt.ranking.FeasibilityFirst`, or the papers'
  cost + residual (:class:`~driveopt.ranking.CostPlusResidual`, :class:`~driveopt.ranking.P1AuthorsRanking`);
- ``fallback`` (:class:`driveopt.fallback.Fallback`): the stops weighed when nothing is feasible and how one is
  chosen, and whether the comfortable and the emergency stop ride in every batch (``in_batch``; P1: the samples
  alone);
- ``row_sharing`` (:mod:`driveopt.row_sharing`): every row projected, or each distinct row once (P2's pipelines,
  whose discrete prior repeats rows).

A method is a frozen dataclass of frozen dataclasses: :func:`driveopt.planner.solve` takes it as one static argument,
so each distinct method is one compilation, and equal methods share it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from driveopt.checks import require
from driveopt.fallback import Fallback
from driveopt.ranking import FeasibilityFirst, Ranking
from driveopt.row_sharing import EveryRow, RowSharing


@dataclass(frozen=True)
class Method:
    """How the planner ranks a batch (``ranking``), what rides in it and what it offers when nothing is feasible
    (``fallback``), and whether it projects repeated rows once (``row_sharing``); driveopt's by default."""

    ranking: Ranking = FeasibilityFirst()  # how a batch's rows are ranked (the papers: CostPlusResidual)
    fallback: Fallback = Fallback()  # the stops weighed when nothing is feasible, and whether two ride in every batch
    row_sharing: RowSharing = EveryRow()  # whether repeated rows are projected once (P2's pipelines: DistinctRows)

    def __post_init__(self) -> None:
        require(isinstance(self.fallback, Fallback), f"method.fallback must be a Fallback, got {self.fallback!r}")
        for name in ("ranking", "row_sharing"):
            value = getattr(self, name)
            try:
                hash(value)
            except TypeError:
                require(False, f"method.{name} must be hashable (a frozen dataclass), got {value!r}")

    def as_papers(self, ranking: Ranking) -> "Method":
        """This method with the papers' rules: ``ranking``, no stop rows in the batches, and a fallback without
        straightening or sideways stops (:data:`PAPERS_FALLBACK`); the row sharing, which changes no rule, is kept."""
        return dataclasses.replace(self, ranking=ranking, fallback=PAPERS_FALLBACK)


DRIVEOPT_METHOD = Method()  # driveopt's: feasible rows first, the stops in every batch, every row projected
PAPERS_FALLBACK = Fallback(straightens=False, evasion=False, in_batch=False)  # P1's and P2's batches hold the samples
# alone; their fallback (followed only on a numerical error) brakes without straightening or sideways stops


def papers_method(ranking: Ranking, row_sharing: RowSharing = EveryRow()) -> Method:
    """The papers' method with ``ranking`` (:meth:`Method.as_papers`): P1's with ``CostPlusResidual`` or
    ``P1AuthorsRanking``, P2's with ``CostPlusResidual`` and, for its discrete prior, ``row_sharing``
    ``DistinctRows``."""
    return Method(row_sharing=row_sharing).as_papers(ranking)
