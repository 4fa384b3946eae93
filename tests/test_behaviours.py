"""Planner behaviours that closed-loop driving depends on."""

import jax
import jax.numpy as jnp
import numpy as np

from driveopt import EgoState, Neighbour, PlanStatus, Road, Scene, build_problem, plan
from driveopt.config import ProjectionConfig, QPConfig
from driveopt.planner import braking_coeffs
from driveopt.problem import is_follower
from driveopt.projection import constraint_residuals
from driveopt.qp import boundary_values, make_model
from driveopt.sampler import GaussianPrior


def test_same_lane_followers_can_be_left_out():
    ego = EgoState(x=0.0, y=4.0, vx=5.0)
    follower, beside_behind, ahead = Neighbour(x=-12.0, y=4.3, vx=15.0), Neighbour(x=-12.0, y=8.0, vx=15.0), Neighbour(x=30.0, y=4.0)
    scene = Scene(ego=ego, neighbours=(follower, beside_behind, ahead))
    assert is_follower(scene, follower) and not is_follower(scene, beside_behind) and not is_follower(scene, ahead)
    kept = build_problem(scene, ignore_followers=True)
    assert float(kept.obstacle_mask.sum()) == 2
    assert float(build_problem(scene).obstacle_mask.sum()) == 3


def test_structured_prior_draws_whole_horizon_behaviours():
    problem = build_problem(Scene(ego=EgoState(x=0.0, y=4.0, vx=12.0), road=Road(num_lanes=4)))
    p = np.asarray(GaussianPrior(structured_fraction=0.5).propose(problem, jax.random.PRNGKey(0), 200).samples)
    structured = p[100:]
    assert np.allclose(structured[:, :4], structured[:, :1])  # one speed held over the horizon
    assert set(np.round(structured[:, 7], 3)) <= {0.0, 4.0, 8.0, 12.0}  # ends on a lane centre
    assert len(set(np.round(structured[:, 7], 3))) == 4
    pure = np.asarray(GaussianPrior(structured_fraction=0.0).propose(problem, jax.random.PRNGKey(0), 200).samples)
    assert not np.any(np.all(np.isclose(pure[:, :4], pure[:, :1]), axis=1))  # P1: independent set-points


def test_a_stop_is_feasible_curvature_is_not_applied_at_standstill():
    model = make_model()
    problem = build_problem(Scene(ego=EgoState(x=0.0, y=4.3, vx=10.0)))
    b_x, b_y = boundary_values(problem.init_x, problem.init_y, QPConfig())
    stop = braking_coeffs(model, problem, 3.0, b_x, b_y)[None]
    res = constraint_residuals(model, problem, stop, ProjectionConfig(a_max=4.5, kappa_max=0.16))
    assert float(res.total[0]) < 0.05
    speed = np.hypot(stop[0, :11] @ np.asarray(model.Wd).T, stop[0, 11:] @ np.asarray(model.Wd).T)
    assert abs(speed[0] - 10.0) < 1e-3
    assert speed[np.searchsorted(np.asarray(model.t), 5.0)] < 0.5  # stopped after 10 / 3 s


def test_a_feasible_stop_beats_infeasible_samples(small_config):
    """Dense wall of cars ahead in every lane: only stopping is safe, and the planner says SUCCESS for it."""
    wall = tuple(Neighbour(x=25.0, y=y, vx=0.0) for y in (0.0, 4.0, 8.0, 12.0))
    scene = Scene(ego=EgoState(x=0.0, y=4.0, vx=8.0), neighbours=wall)
    result = plan(build_problem(scene, small_config.basis), small_config, key=jax.random.PRNGKey(0))
    assert result.status == PlanStatus.SUCCESS
    assert float(jnp.max(jnp.asarray(result.trajectory.x))) < 25.0 - 7.0  # stops before the wall's ellipses
