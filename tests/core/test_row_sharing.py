"""Row sharing (:mod:`driveopt.row_sharing`): identical rows are found exactly, a batch's distinct rows projected in
chunks come out as the whole batch projected at once, and a planner that shares rows picks what one that projects
every row picks."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_solve import FixedPrior

from driveopt.checks import ConfigError
from driveopt.config import PlannerConfig
from driveopt.method import Method
from driveopt.planner import plan, project_batch, setpoint_batch
from driveopt.problem import build_problem
from driveopt.qp import make_model
from driveopt.registry import get_optimiser
from driveopt.row_sharing import DistinctRows, EveryRow, distinct_rows
from driveopt.sampler import default_mean, sample_gaussian
from driveopt.scene import load_scene

CONFIG = PlannerConfig().replace(sampler=dict(num_samples=24, num_iterations=1, num_constraint_elites=12, num_elites=6),
                                 projection=dict(max_iterations=10, barrier=True))


def _repeated(rows: np.ndarray, copies: int, seed: int = 0) -> np.ndarray:
    """``rows`` each repeated ``copies`` times, shuffled."""
    batch = np.repeat(rows, copies, axis=0)
    return batch[np.random.default_rng(seed).permutation(len(batch))]


def test_distinct_rows_groups_identical_rows_and_only_those():
    base = np.random.default_rng(1).normal(size=(9, 5)).astype(np.float32)
    base[1] = base[0]
    base[1, 3] = np.nextafter(base[0, 3], np.float32(np.inf))  # one bit apart: a row of its own
    base[2] = -0.0 * base[2]  # -0.0 and 0.0 differ in their bits: kept apart, which is only less sharing
    base[3] = 0.0 * base[3]
    rows = _repeated(base, 3)
    member, count, group = (np.asarray(a) for a in distinct_rows(jnp.asarray(rows)))
    assert count == len(np.unique(rows.view(np.uint32), axis=0)) == 9
    np.testing.assert_array_equal(rows[member[group]], rows)  # every row reads a copy of itself, bit for bit
    kept = rows[member[:count]]
    assert len(np.unique(kept.view(np.uint32), axis=0)) == count  # one member per group
    assert group.max() == count - 1 and set(group) == set(range(count))


def _projection_case(terminal_position: bool, copies: int = 3):
    config = CONFIG.replace(qp={"terminal_position": terminal_position}) if terminal_position else CONFIG
    problem = build_problem(load_scene("dense-snapshot"), config.basis)
    model = make_model(config.basis, config.qp)
    setpoints = sample_gaussian(jax.random.PRNGKey(0), default_mean(problem), jnp.eye(8) * 2.0, 7)
    coeffs, b_x, b_y = setpoint_batch(model, problem, config, jnp.asarray(_repeated(np.asarray(setpoints), copies)))
    return config, problem, model, coeffs, b_x, b_y


@pytest.mark.parametrize("terminal_position, tolerance", [  # boundary values shared, or one set per row (goals); fixed
    (False, 1e-3),                                           # work, or the early stop (the other three pairings: slow)
    pytest.param(True, 0.0, marks=pytest.mark.slow), pytest.param(False, 0.0, marks=pytest.mark.slow),
    pytest.param(True, 1e-3, marks=pytest.mark.slow)])
def test_distinct_rows_in_chunks_project_as_the_whole_batch(terminal_position, tolerance):
    config, problem, model, coeffs, b_x, b_y = _projection_case(terminal_position)
    config = config.replace(projection={"tolerance": tolerance})
    assert (b_x.ndim == 2) == terminal_position

    def project_rows(c, bx, by):
        return project_batch(model, problem, config, c, bx, by)

    whole = jax.jit(lambda c: EveryRow().project(project_rows, c, b_x, b_y))(coeffs)
    # 7 distinct rows: two chunks of 3 and one of 2 (its second row a filler), or one chunk larger than the batch
    for chunks in ((3, 2), (64,)):
        shared = jax.jit(lambda c: DistinctRows(chunks).project(project_rows, c, b_x, b_y))(coeffs)
        np.testing.assert_allclose(shared.coeffs, whole.coeffs, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(shared.multipliers, whole.multipliers, rtol=1e-4, atol=1e-4)
        for family in whole.residuals._fields:
            np.testing.assert_allclose(getattr(shared.residuals, family), getattr(whole.residuals, family), atol=1e-5)
        if tolerance == 0.0:  # fixed work: the same iterations and status
            assert int(shared.iterations) == int(whole.iterations) == config.projection.max_iterations
            assert int(shared.status) == int(whole.status)
    assert float(jnp.max(whole.residuals.total)) > 0.0  # the rows were projected, not already feasible


def test_a_batch_of_distinct_rows_projects_as_the_whole_batch_with_any_chunk_sizes():
    """7 rows, all distinct, in chunks of 4 then 3 (not a multiple of 3): the last chunk reaches past the batch."""
    config, problem, model, coeffs, b_x, b_y = _projection_case(False, copies=1)
    config = config.replace(projection={"tolerance": 0.0})

    def project_rows(c, bx, by):
        return project_batch(model, problem, config, c, bx, by)

    whole = jax.jit(lambda c: EveryRow().project(project_rows, c, b_x, b_y))(coeffs)
    shared = jax.jit(lambda c: DistinctRows((4, 3)).project(project_rows, c, b_x, b_y))(coeffs)
    np.testing.assert_allclose(shared.coeffs, whole.coeffs, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(shared.residuals.total, whole.residuals.total, atol=1e-5)


@pytest.mark.slow  # suite time: run with -m slow
def test_a_planner_sharing_rows_picks_what_one_projecting_every_row_picks():
    problem = build_problem(load_scene("dense-snapshot"), CONFIG.basis)
    distinct = np.asarray(sample_gaussian(jax.random.PRNGKey(4), default_mean(problem), jnp.eye(8) * 3.0, 6))
    batch = FixedPrior(jnp.asarray(_repeated(distinct, 4)))
    every = plan(problem, CONFIG, key=jax.random.PRNGKey(0), prior=batch)
    shared = plan(problem, CONFIG, key=jax.random.PRNGKey(0), prior=batch, method=Method(row_sharing=DistinctRows((4, 2))))
    assert shared.status == every.status
    np.testing.assert_array_equal(shared.setpoints, every.setpoints)
    np.testing.assert_allclose(shared.costs["total"], every.costs["total"], rtol=1e-5)
    np.testing.assert_allclose(shared.first.residual, every.first.residual, atol=1e-5)


def test_row_sharing_is_checked_and_p2_pipelines_share_rows():
    for chunks in ((), (64, 0)):
        with pytest.raises(ConfigError, match="chunks"):
            DistinctRows(chunks)
    for name in ("vqvae", "vqvae-filter", "vqvae-faithful", "vqvae-filter-faithful"):
        assert isinstance(get_optimiser(name).method.row_sharing, DistinctRows), name
    for name in ("bilevel", "cvae-filter", "vqvae-cem"):  # continuous samples, or a sampler that iterates
        assert get_optimiser(name).method.row_sharing == EveryRow(), name
