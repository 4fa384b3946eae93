"""The previous plan's row: its set-points re-solved (the default) or the plan itself moved on (ShiftedPlan)."""

import dataclasses

import jax
import numpy as np
import pytest

from driveopt import EgoState, Neighbour, PlanStatus, Scene, build_problem, plan
from driveopt.basis import basis_at
from driveopt.carried_row import ResolvedSetpoints, ShiftedPlan
from driveopt.method import Method
from driveopt.planner import PreviousPlan, RowKind, previous_plan
from driveopt.scene import ProblemError

ELAPSED = 0.5  # [s] between the two calls


def _traffic(ego_x: float = 0.0, ego_y: float = 4.0, vx: float = 12.0, vy: float = 0.0, ax: float = 0.0,
             ay: float = 0.0, t: float = 0.0) -> Scene:
    """Ego at ``vx`` in a three-lane road (lanes at 0, 4, 8 m) with a slow car ahead in its lane and cars beside,
    every neighbour moved on by ``t`` [s] at its speed."""
    cars = ((30.0, 4.0, 6.0), (10.0, 8.0, 13.0), (-5.0, 0.0, 12.0), (45.0, 0.0, 11.0))
    return Scene(ego=EgoState(x=ego_x, y=ego_y, vx=vx, vy=vy, ax=ax, ay=ay),
                 neighbours=tuple(Neighbour(x=x + v * t, y=y, vx=v) for x, y, v in cars))


def _two_calls(config, method):
    """The first call's result and the second call's, ``ELAPSED`` later from the state the first plan put the car in."""
    first = plan(build_problem(_traffic(), config.basis), config, key=jax.random.PRNGKey(0), method=method)
    assert first.status == PlanStatus.SUCCESS
    traj = first.trajectory
    at = lambda values: float(np.interp(ELAPSED, traj.t, values))  # noqa: E731
    ax, ay = (at(np.gradient(np.asarray(v), np.asarray(traj.t))) for v in (traj.vx, traj.vy))
    scene = _traffic(at(traj.x), at(traj.y), at(traj.vx), at(traj.vy), ax, ay, ELAPSED)
    previous = previous_plan(first, ELAPSED)
    second = plan(build_problem(scene, config.basis), config, key=jax.random.PRNGKey(1), method=method,
                  previous=previous, x_offset=scene.ego.x)
    return first, previous, second


def test_the_carried_coefficients_are_the_executed_plan_moved_on(small_config):
    first = plan(build_problem(_traffic(), small_config.basis), small_config, key=jax.random.PRNGKey(0))
    previous = previous_plan(first, ELAPSED)
    traj, basis = first.safe_trajectory, small_config.basis
    W = basis_at(basis.order, basis.horizon, np.asarray(traj.t)).W
    n = basis.order + 1
    x, y = W @ previous.coeffs[:n], W @ previous.coeffs[n:]
    inside = np.asarray(traj.t) + ELAPSED <= traj.t[-1]
    later = np.asarray(traj.t)[inside] + ELAPSED
    moved_x = np.interp(later, traj.t, traj.x) - np.interp(ELAPSED, traj.t, traj.x)
    assert np.max(np.abs(x[inside] - moved_x)) < 0.1  # [m] (a least-squares fit), over 280 m
    assert np.max(np.abs(y[inside] - np.interp(later, traj.t, traj.y))) < 0.02
    assert x[0] == pytest.approx(0.0, abs=0.05)  # from where the plan had the car


@pytest.mark.parametrize("window", [0, 4])
def test_the_shifted_plan_is_the_rows_target_and_stays_feasible(small_config, window):
    """The world as the first call predicted it and the car where its plan put it: under P2's barrier projection
    (50 iterations, plain or accelerated) the moved-on plan's row stays within the tolerance; the re-solved set-points'
    row does not after 50 plain iterations."""
    config = small_config.replace(projection={"barrier": True, "max_iterations": 50, "anderson_window": window})
    row, tolerance = config.sampler.num_samples, config.sampler.residual_tolerance
    _, previous, shifted = _two_calls(config, Method(carried_row=ShiftedPlan()))
    assert int(shifted.first.kind[row]) == RowKind.PREVIOUS_PLAN
    np.testing.assert_array_equal(np.asarray(shifted.first.qp_coeffs[row]), previous.coeffs)
    assert float(shifted.first.residual[row]) <= tolerance
    if window == 0:
        _, _, resolved = _two_calls(config, Method())
        assert float(resolved.first.residual[row]) > tolerance


def test_the_default_row_does_not_read_the_carried_coefficients(small_config):
    first = plan(build_problem(_traffic(), small_config.basis), small_config, key=jax.random.PRNGKey(0))
    previous = previous_plan(first, ELAPSED)
    problem = build_problem(_traffic(t=ELAPSED), small_config.basis)
    results = [plan(problem, small_config, key=jax.random.PRNGKey(1), previous=p, method=Method(carried_row=ResolvedSetpoints()))
               for p in (previous, previous._replace(coeffs=None), previous._replace(coeffs=previous.coeffs + 3.0))]
    for other in results[1:]:
        np.testing.assert_array_equal(other.coeffs, results[0].coeffs)
        np.testing.assert_array_equal(np.asarray(other.first.residual), np.asarray(results[0].first.residual))


def test_a_shifted_plan_row_without_coefficients_is_refused(small_config):
    problem = build_problem(_traffic(), small_config.basis)
    bare = PreviousPlan(np.full(8, 4.0, np.float32), np.full(small_config.basis.num_nodes, 4.0, np.float32))
    with pytest.raises(ProblemError, match="PreviousPlan.coeffs"):
        plan(problem, small_config, key=jax.random.PRNGKey(0), previous=bare, method=Method(carried_row=ShiftedPlan()))
    # the absent plan's placeholder has none and needs none
    absent = PreviousPlan.absent(small_config.basis.num_nodes)
    assert plan(problem, small_config, key=jax.random.PRNGKey(0), previous=absent,
                method=Method(carried_row=ShiftedPlan())).status == PlanStatus.SUCCESS
    with pytest.raises(ProblemError, match="previous plan must be finite"):
        plan(problem, small_config, key=jax.random.PRNGKey(0), method=Method(carried_row=ShiftedPlan()),
             previous=bare._replace(coeffs=np.zeros(5)))
