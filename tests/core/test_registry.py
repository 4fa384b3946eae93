"""Planner registry and the baseline proposal distributions."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from driveopt.batch_rows import SamplesOnly, StopRows
from driveopt.errors import UnknownNameError
from driveopt.fallback import Fallback
from driveopt.planner import goal_from_setpoints, plan
from driveopt.priors.grids import GoalGridPrior, GridPrior
from driveopt.problem import build_problem
from driveopt.qp import boundary_values, make_model, solve_setpoint_qp
from driveopt.ranking import CostPlusResidual, FeasibilityFirst
from driveopt.registry import P1_RANKING_COST_WEIGHT, get_optimiser, get_planner, list_planners
from driveopt.scene import load_scene


def test_registry_names_and_clear_error():
    assert {"bilevel", "random", "grid", "vanilla", "batch", "idm"} <= set(list_planners())
    assert {"random-p1", "grid-p1", "vanilla-p1", "batch-p1"} <= set(list_planners())
    with pytest.raises(UnknownNameError, match="valid planners: bilevel"):
        get_planner("nope")
    with pytest.raises(UnknownNameError, match="optimisers: bilevel"):
        get_optimiser("idm")
    assert get_optimiser("grid") is get_planner("grid")


def test_batch_size_override_caps_elites_and_keeps_vanilla_single():
    bilevel = get_planner("bilevel").with_samples(60).config.sampler
    assert (bilevel.num_samples, bilevel.num_constraint_elites, bilevel.num_elites) == (60, 60, 40)
    assert get_planner("vanilla").with_samples(250).config.sampler.num_samples == 1  # one sample is the method
    assert get_planner("grid").with_samples(None) == get_planner("grid")
    assert get_planner("idm").with_samples(250) == get_planner("idm")


@pytest.mark.parametrize("name", ["random", "grid", "vanilla", "batch"])
def test_baselines_plan_finite_trajectories(name):
    spec = get_planner(name).with_overrides(projection={"max_iterations": 10})
    scene = load_scene("dense-snapshot")
    result = plan(build_problem(scene, spec.config.basis), spec.config, key=jax.random.PRNGKey(0), prior=spec.prior())
    for arr in (*result.trajectory, result.coeffs, result.setpoints):
        assert np.all(np.isfinite(arr))
    assert result.history.best_score.shape == (1,)  # no adaptation: a single sampler iteration


@pytest.mark.parametrize("name", ["random", "grid", "vanilla", "batch"])
def test_p1_faithful_baselines_differ_only_in_what_p1_did_not_have(name):
    base, p1 = get_optimiser(name), get_optimiser(f"{name}-p1")
    assert p1.config == base.config.replace(sampler={"structured_fraction": 0.0}, qp={"initial_lateral_acceleration": True},
                                            cost={"consistency": 0.0}, projection={"course_max": 0.0, "ego_turn_rate": 0.0})
    assert base.config.projection.course_max > 0 and base.config.projection.ego_turn_rate > 0
    # three strategies swapped, and the driver's contact guard off
    assert (p1.ranking, p1.batch_rows, p1.fallback) == (CostPlusResidual(P1_RANKING_COST_WEIGHT), SamplesOnly(),
                                                         Fallback(straightens=False, evasion=False))
    assert (base.ranking, base.batch_rows, base.fallback) == (FeasibilityFirst(), StopRows(), Fallback())
    assert base.contact_guard and not p1.contact_guard
    assert p1.make_prior is base.make_prior and p1.fixed_batch == base.fixed_batch and p1.warm_start == base.warm_start
    assert (p1.executes_infeasible, p1.braking_prediction, p1.replan_every) == (True, False, 5)
    assert (base.executes_infeasible, base.braking_prediction, base.replan_every) == (False, True, 1)
    assert p1.description.startswith("P1-faithful")
    assert p1.with_replan_every(1).replan_every == 1  # bench --replan-every still overrides it


def test_grid_prior_covers_lanes_speeds_and_only_valid_lanes():
    problem = build_problem(load_scene("dense-snapshot"))  # 4 lanes centred at 0, 4, 8, 12
    p = np.asarray(GridPrior(num_speeds=10).propose(problem, jax.random.PRNGKey(0), 160).samples)
    assert p.shape == (160, 8)
    assert set(np.round(p[:, 7], 3)) == {0.0, 4.0, 8.0, 12.0}  # every lane is a target, nothing else
    assert len(set(np.round(p[:, 0], 3))) == 10
    # The same problem always gives the same grid (no randomness).
    q = np.asarray(GridPrior(num_speeds=10).propose(problem, jax.random.PRNGKey(5), 160).samples)
    np.testing.assert_array_equal(p, q)


def test_goal_grid_trajectories_reach_their_goals():
    spec = get_planner("batch")
    problem = build_problem(load_scene("static-blockage"), spec.config.basis)
    p = GoalGridPrior().propose(problem, jax.random.PRNGKey(0), 50).samples
    goal = goal_from_setpoints(p, problem.init_x, spec.config.basis.horizon)
    model = make_model(spec.config.basis, spec.config.qp)
    b_x, b_y = boundary_values(problem.init_x, problem.init_y, spec.config.qp, goal)
    c = solve_setpoint_qp(model, p, b_x, b_y)
    end_x, end_y = c[:, :11] @ model.W[-1], c[:, 11:] @ model.W[-1]
    np.testing.assert_allclose(end_x, goal[:, 0], atol=1e-2 * float(jnp.max(goal[:, 0])))
    np.testing.assert_allclose(end_y, goal[:, 1], atol=1e-3)
