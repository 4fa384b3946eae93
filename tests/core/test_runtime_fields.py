"""The configuration's runtime fields (``config.RUNTIME_FIELDS``): inputs of the compiled planner, so that
configurations that differ only in them share one compilation, with the results of the values compiled in (that a plan
with them is bit for bit the plan compiled with them: tests/core/test_behaviours.py, beside the previous-plan test whose
compilation it shares)."""

import dataclasses

import jax
import numpy as np
import pytest
from conftest import RUNTIME_CHANGES

from driveopt.config import RUNTIME_FIELDS, PlannerConfig, split_runtime, with_runtime

TINY = PlannerConfig().replace(sampler=dict(num_samples=19, num_iterations=2, num_constraint_elites=8, num_elites=4))


def test_the_other_values_cover_every_runtime_field():
    assert {section: tuple(fields) for section, fields in RUNTIME_CHANGES.items()} == RUNTIME_FIELDS
    changed = TINY.replace(**RUNTIME_CHANGES)
    for section, fields in RUNTIME_CHANGES.items():
        assert all(getattr(getattr(changed, section), name) != getattr(getattr(TINY, section), name) for name in fields)


def test_split_keeps_every_other_field_and_joins_back_to_the_configuration():
    changed = TINY.replace(**RUNTIME_CHANGES)
    static, runtime = split_runtime(changed)
    assert static == split_runtime(TINY)[0] == TINY.replace(**{s: {n: getattr(getattr(PlannerConfig(), s), n) for n in f}
                                                            for s, f in RUNTIME_FIELDS.items()})
    assert runtime == {s: {n: np.float32(v) for n, v in f.items()} for s, f in RUNTIME_CHANGES.items()}
    joined = with_runtime(static, {s: {n: float(v) for n, v in f.items()} for s, f in RUNTIME_CHANGES.items()})
    assert joined == changed and hash(joined) == hash(changed)
    assert static.sampler == changed.sampler and static.basis == changed.basis  # no other field moves


def test_runtime_values_reach_the_planner_as_given():
    static, runtime = split_runtime(TINY.replace(**RUNTIME_CHANGES))
    traced = jax.jit(lambda values: with_runtime(static, values).projection.a_max * 2.0)(runtime)
    assert float(traced) == pytest.approx(9.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        static.projection.a_max = 1.0  # the copies are new objects: the static configuration is untouched
