"""solve(): the pure, jittable, differentiable optimiser behind plan(); status decided inside; row kinds."""

import jax
import jax.numpy as jnp
import numpy as np

from driveopt.planner import PlanStatus, RowKind, compiled_solve, plan, previous_plan, solve
from driveopt.priors.gaussian import GaussianPrior
from driveopt.problem import build_problem
from driveopt.safety import FilterInit
from driveopt.scene import load_scene

TINY = dict(sampler=dict(num_samples=24, num_iterations=2, num_constraint_elites=12, num_elites=6),
            projection=dict(max_iterations=4))


class OffsetFilter:
    """Test filter: starts the projection from the QP solutions plus a learned offset (one leaf)."""

    def __init__(self, offset):
        self.offset = offset

    def initialise(self, problem, coeffs):
        return FilterInit(jnp.float32(1.0), jnp.float32(1.0), coeffs + self.offset, jnp.zeros_like(coeffs))


jax.tree_util.register_pytree_node(OffsetFilter, lambda f: ((f.offset,), None), lambda _, leaves: OffsetFilter(*leaves))


def test_grad_through_solve_with_respect_to_the_initial_coefficients_is_finite(small_config):
    config = small_config.replace(**TINY)
    problem = build_problem(load_scene("dense-snapshot"), config.basis)
    prior = GaussianPrior.from_config(config.sampler, config.projection.v_max)
    n = 2 * (config.basis.order + 1)

    def loss(offset):
        solution = solve(problem, jax.random.PRNGKey(0), config, prior, safety_filter=OffsetFilter(offset), unroll=True)
        return jnp.sum(solution.trajectory.y ** 2) + jnp.sum(solution.best.residuals)

    grad = jax.jit(jax.grad(loss))(jnp.zeros(n, jnp.float32))
    assert grad.shape == (n,) and np.all(np.isfinite(grad)) and np.any(grad != 0.0)


def test_status_is_decided_inside_the_compiled_call_and_matches_plan(small_config):
    config = small_config.replace(**TINY)
    for name in ("static-blockage", "dense-snapshot"):
        scene = load_scene(name)
        problem = build_problem(scene, config.basis)
        prior = GaussianPrior.from_config(config.sampler, config.projection.v_max)
        solution = compiled_solve()(problem, jax.random.PRNGKey(3), config, prior)
        result = plan(problem, config, key=jax.random.PRNGKey(3), prior=prior)
        assert solution.status.dtype == jnp.int32 and PlanStatus(int(solution.status)) == result.status
        assert bool(solution.history.best_feasible[-1]) == (result.status == PlanStatus.SUCCESS)


def test_appended_rows_carry_their_kind(small_config):
    config = small_config.replace(**TINY)
    problem = build_problem(load_scene("static-blockage"), config.basis)
    first = plan(problem, config, key=jax.random.PRNGKey(0))
    kinds = list(first.first.kind)
    assert kinds[-2:] == [RowKind.COMFORTABLE_STOP, RowKind.EMERGENCY_STOP] and kinds.count(RowKind.SAMPLE) == 24
    again = plan(problem, config, key=jax.random.PRNGKey(1), previous=previous_plan(first, 0.1))
    assert list(again.last.kind[-3:]) == [RowKind.PREVIOUS_PLAN, RowKind.COMFORTABLE_STOP, RowKind.EMERGENCY_STOP]
    assert len(again.last.kind) == len(again.last.residual) == 27
    assert set(np.asarray(again.history.projection_status)) <= {0, 1}  # ProjectionStatus values reach the result
