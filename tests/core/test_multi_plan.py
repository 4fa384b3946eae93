"""plan_many: E problems in one compiled call give, per problem, what plan gives one by one (same keys).

Tolerance. The mapped call runs the same operations as E separate calls, but XLA orders the float32 sums of the
batched matrix products differently, so results agree to rounding, not bit for bit. The first sampler iteration draws
the very same set-points (the keys are the same), and its set-point QP agrees to float32 rounding of values of up to
a few hundred metres (atol 1e-3). Later iterations adapt the Gaussian to elites ranked on those values, which can turn
a last-bit difference into another sample drawn, so the chosen plans agree only as near-equal candidates do: the same
status, lateral positions within 0.05 m, costs within 1 % (measured: at most 4 mm and 0.05 % on these problems).
"""

import jax
import numpy as np
import pytest

from driveopt import build_problem, load_scene, plan
from driveopt.multi_plan import Call, plan_many
from driveopt.planner import PreviousPlan, previous_plan
from driveopt.scene import ProblemError

SCENES = ("dense-snapshot", "static-blockage", "slow-leader-four-lane")


def calls_of(config):
    scenes = [load_scene(name) for name in SCENES]
    problems = [build_problem(scene, config.basis) for scene in scenes]
    keys = [jax.random.PRNGKey(i) for i in range(len(scenes))]
    absent = PreviousPlan.absent(config.basis.num_nodes)
    first = plan(problems[0], config, key=keys[0], previous=absent, x_offset=scenes[0].ego.x)
    # a mix: no warm start and the absent previous plan; a warm start and a real previous plan
    return [Call(problems[0], keys[0], None, absent, scenes[0].ego.x),
            Call(problems[1], keys[1], first.mean, previous_plan(first, 0.1), scenes[1].ego.x),
            Call(problems[2], keys[2], None, absent, scenes[2].ego.x)]


@pytest.mark.slow  # compiles the batched planner: about 100 s on two busy cores (the refusals below run by default)
def test_each_call_of_a_padded_batch_plans_what_plan_plans_alone(small_config):
    config = small_config.replace(cost={"consistency": 1.0})
    calls = calls_of(config)
    alone = [plan(c.problem, config, key=c.key, warm_start=c.warm_start, previous=c.previous, x_offset=c.x_offset)
             for c in calls]
    together = plan_many(calls, config, slots=4)  # one slot of padding
    assert len(together) == len(calls)
    for a, b in zip(alone, together):
        assert b.status == a.status
        assert b.first.setpoints.shape == a.first.setpoints.shape  # the placeholder row removed where absent
        np.testing.assert_array_equal(b.first.setpoints, a.first.setpoints)
        np.testing.assert_allclose(b.first.qp_coeffs, a.first.qp_coeffs, atol=1e-3)
        np.testing.assert_allclose(b.trajectory.y, a.trajectory.y, atol=0.05)
        np.testing.assert_allclose(b.trajectory.x, a.trajectory.x, rtol=1e-2, atol=0.5)
        assert b.costs["total"] == pytest.approx(a.costs["total"], rel=1e-2)
        assert b.x_offset == a.x_offset and np.all(np.isfinite(b.fallback.x))


@pytest.mark.slow  # compiles the planner with a previous plan: about 70 s on two busy cores
def test_one_slot_is_plan_itself_bit_for_bit(small_config):
    """A lock-step run of one episode at a time records what the one-by-one loop records."""
    call = calls_of(small_config)[1]  # a warm start and a real previous plan
    alone = plan(call.problem, small_config, key=call.key, warm_start=call.warm_start, previous=call.previous,
                 x_offset=call.x_offset)
    (together,) = plan_many([call], small_config, slots=1)
    assert together.status == alone.status and together.costs == alone.costs
    for a, b in zip(jax.tree_util.tree_leaves(alone.trajectory) + [alone.mean, alone.coeffs],
                    jax.tree_util.tree_leaves(together.trajectory) + [together.mean, together.coeffs]):
        np.testing.assert_array_equal(a, b)


def test_bad_batches_are_refused_in_one_line(small_config):
    problem = build_problem(load_scene("dense-snapshot"), small_config.basis)
    key = jax.random.PRNGKey(0)
    with pytest.raises(ProblemError, match="at least one call"):
        plan_many([], small_config)
    with pytest.raises(ProblemError, match="slots must be an integer >= the 2 calls"):
        plan_many([Call(problem, key), Call(problem, key)], small_config, slots=1)
    absent = PreviousPlan.absent(small_config.basis.num_nodes)
    with pytest.raises(ProblemError, match="every call carries a previous plan"):
        plan_many([Call(problem, key), Call(problem, key, previous=absent)], small_config)
    with pytest.raises(ProblemError, match="one kind"):
        plan_many([Call(problem, key), Call(problem, jax.random.key(1))], small_config)
    with pytest.raises(ProblemError, match="key must be"):
        plan_many([Call(problem, np.zeros(3, np.uint32))], small_config)
