"""The configuration's runtime fields (``config.RUNTIME_FIELDS``): inputs of the compiled planner, so that
configurations that differ only in them share one compilation, with the results of the values compiled in."""

import dataclasses

import jax
import numpy as np
import pytest

from driveopt.config import RUNTIME_FIELDS, PlannerConfig, split_runtime, with_runtime
from driveopt.fallback import Fallback
from driveopt.planner import PlanStatus, PreviousPlan, WarmStart, _to_result, compiled_solve, plan, previous_plan
from driveopt.problem import build_problem
from driveopt.sampler import GaussianPrior
from driveopt.scene import load_scene

TINY = PlannerConfig().replace(sampler=dict(num_samples=19, num_iterations=2, num_constraint_elites=8, num_elites=4))
# every runtime field at another value than TINY's
OTHER = {"projection": {"v_min": 0.5, "a_max": 4.5},
         "cost": {"speed": 2.0, "lateral_acceleration": 0.1, "heading": 10.0, "curvature": 5.0, "lane_centering": 1.0,
                  "consistency": 1.0}}


def test_the_other_values_cover_every_runtime_field():
    assert {section: tuple(fields) for section, fields in OTHER.items()} == RUNTIME_FIELDS
    changed = TINY.replace(**OTHER)
    for section, fields in OTHER.items():
        assert all(getattr(getattr(changed, section), name) != getattr(getattr(TINY, section), name) for name in fields)


def test_split_keeps_every_other_field_and_joins_back_to_the_configuration():
    changed = TINY.replace(**OTHER)
    static, runtime = split_runtime(changed)
    assert static == split_runtime(TINY)[0] == TINY.replace(**{s: {n: getattr(getattr(PlannerConfig(), s), n) for n in f}
                                                            for s, f in RUNTIME_FIELDS.items()})
    assert runtime == {s: {n: np.float32(v) for n, v in f.items()} for s, f in OTHER.items()}
    joined = with_runtime(static, {s: {n: float(v) for n, v in f.items()} for s, f in OTHER.items()})
    assert joined == changed and hash(joined) == hash(changed)
    assert static.sampler == changed.sampler and static.basis == changed.basis  # no other field moves


def test_a_plan_with_runtime_fields_is_bit_for_bit_the_plan_compiled_with_them_and_shares_one_compilation(small_config,
                                                                                                          solve_graphs):
    """The shared small configuration (its runtime fields at their defaults) with a previous plan: the graph the
    behaviour tests compile; the reference compiles the changed configuration in as constants."""
    problem = build_problem(load_scene("dense-snapshot"), small_config.basis)
    changed = small_config.replace(**OTHER)
    prior = GaussianPrior.from_config(changed.sampler, changed.projection.v_max)
    first = plan(problem, small_config, key=jax.random.PRNGKey(0), prior=prior,
                 previous=PreviousPlan.absent(small_config.basis.num_nodes))
    previous = previous_plan(first, 0.1)  # so that the consistency weight acts
    kwargs = dict(key=jax.random.PRNGKey(1), prior=prior, previous=previous)
    result = plan(problem, changed, **kwargs)
    default = plan(problem, small_config, **kwargs)
    assert len(set(solve_graphs)) == 1  # the configuration and its changed copy: one compiled planner

    reference = _to_result(jax.device_get(compiled_solve()(problem, kwargs["key"], changed, prior, WarmStart.absent(),
                                                           previous)), changed, Fallback(), 0.0)
    assert result.status == reference.status and result.status != PlanStatus.NUMERICAL_ERROR
    leaves, want = jax.tree_util.tree_flatten_with_path(result)[0], jax.tree_util.tree_leaves(reference)
    assert len(leaves) == len(want) > 50
    for (path, got), expected in zip(leaves, want):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(expected), err_msg=jax.tree_util.keystr(path))

    # and the values act: TINY's own give another plan, weighed by other weights
    assert result.costs != default.costs
    assert not np.array_equal(result.coeffs, default.coeffs)


def test_runtime_values_reach_the_planner_as_given():
    static, runtime = split_runtime(TINY.replace(**OTHER))
    traced = jax.jit(lambda values: with_runtime(static, values).projection.a_max * 2.0)(runtime)
    assert float(traced) == pytest.approx(9.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        static.projection.a_max = 1.0  # the copies are new objects: the static configuration is untouched
