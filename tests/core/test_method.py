"""The planner's method: driveopt's defaults, the papers' rules as one value, the stops of a batch, one compilation per
distinct method."""

import dataclasses

import jax
import pytest

from driveopt.checks import ConfigError
from driveopt.fallback import HOLD, LANE_CENTRE, Fallback
from driveopt.method import DRIVEOPT_METHOD, PAPERS_FALLBACK, Method, papers_method
from driveopt.planner import RowKind, compiled_solve
from driveopt.problem import build_problem
from driveopt.ranking import CostPlusResidual, FeasibilityFirst, P1AuthorsRanking
from driveopt.row_sharing import DistinctRows, EveryRow
from driveopt.sampler import GaussianPrior
from driveopt.scene import load_scene


def test_the_default_method_is_driveopts():
    """Feasible rows first, the comfortable and emergency stops in every batch and weighed as the fallback (straightening,
    sideways stops), every row projected."""
    assert Method() == DRIVEOPT_METHOD == Method(FeasibilityFirst(1.0), Fallback(3.0, True, True, True), EveryRow())
    assert DRIVEOPT_METHOD.fallback.in_batch and DRIVEOPT_METHOD.fallback.batch_stops(5.0) == ((3.0, LANE_CENTRE), (5.0, HOLD))


def test_the_papers_method_swaps_ranking_and_fallback_and_keeps_the_row_sharing():
    p1 = papers_method(CostPlusResidual(1e-5))
    assert p1 == Method(CostPlusResidual(1e-5), Fallback(straightens=False, evasion=False, in_batch=False), EveryRow())
    assert p1.fallback == PAPERS_FALLBACK and PAPERS_FALLBACK.batch_stops(5.0) == ()
    shared = Method(row_sharing=DistinctRows())
    assert shared.as_papers(P1AuthorsRanking()) == Method(P1AuthorsRanking(), PAPERS_FALLBACK, DistinctRows())
    assert papers_method(CostPlusResidual(), DistinctRows()) == shared.as_papers(CostPlusResidual())


def test_methods_are_values_a_jit_can_key_on():
    assert hash(Method()) == hash(Method(FeasibilityFirst(), Fallback(), EveryRow()))
    assert Method(fallback=Fallback(in_batch=False)) != Method()
    with pytest.raises(dataclasses.FrozenInstanceError):
        Method().ranking = CostPlusResidual()
    with pytest.raises(ConfigError, match="method.fallback"):
        Method(fallback={"deceleration": 3.0})
    with pytest.raises(ConfigError, match="fallback.in_batch"):
        Fallback(in_batch="no")


def test_equal_methods_share_one_compilation_and_the_stops_ride_in_the_batch(small_config):
    """Equal methods (built apart) share a compilation, and driveopt's method appends its two stops to every batch (a
    method without them: tests/core/test_solve.py::test_without_stop_rows_the_batch_is_the_samples_alone)."""
    config = small_config.replace(sampler={"num_samples": 6, "num_iterations": 1, "num_constraint_elites": 6, "num_elites": 3},
                                  projection={"max_iterations": 2})
    problem = build_problem(load_scene("static-blockage"), config.basis)
    prior = GaussianPrior.from_config(config.sampler, config.projection.v_max)
    solve = compiled_solve()
    before = solve._cache_size()
    with_stops = solve(problem, jax.random.PRNGKey(0), config, prior, method=Method())
    again = solve(problem, jax.random.PRNGKey(0), config, prior, method=Method(FeasibilityFirst(), Fallback(), EveryRow()))
    assert solve._cache_size() == before + 1
    assert list(with_stops.first.kind) == [RowKind.SAMPLE] * 6 + [RowKind.COMFORTABLE_STOP, RowKind.EMERGENCY_STOP]
    assert (again.first.setpoints == with_stops.first.setpoints).all()
