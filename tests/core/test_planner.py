"""End-to-end planning: the static-blockage manoeuvre, failure handling, properties over random problems."""


import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import box_corners, boxes_overlap
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from driveopt import EgoState, Neighbour, PlanStatus, ProblemError, Road, Scene, build_problem, load_scene, plan
from driveopt.planner import WarmStart
from driveopt.projection import constraint_residuals
from driveopt.qp import make_model


def collides(traj, scene: Scene) -> bool:
    """Exact oriented-rectangle check of the ego against every neighbour at every node."""
    ego = scene.ego
    for k in range(len(traj.t)):
        ego_box = box_corners(traj.x[k], traj.y[k], traj.heading[k], ego.length, ego.width)
        for n in scene.neighbours:
            t = traj.t[k]
            other = box_corners(n.x + n.vx * t, n.y + n.vy * t, n.heading, n.length, n.width)
            if boxes_overlap(ego_box, other):
                return True
    return False


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_static_blockage_changes_into_the_free_lane(small_config, seed):
    scene = load_scene("static-blockage")
    result = plan(build_problem(scene, small_config.basis), small_config, key=jax.random.PRNGKey(seed), x_offset=scene.ego.x)
    assert result.status == PlanStatus.SUCCESS
    traj = result.trajectory
    blocker = scene.neighbours[0]
    y_at_blocker = np.interp(blocker.x, traj.x, traj.y)
    assert 6.0 < y_at_blocker < 10.5, f"expected lane 2 (y = 8) when passing the blocker, got y = {y_at_blocker:.2f}"
    assert not collides(traj, scene)
    assert result.residuals["total"] <= small_config.sampler.residual_tolerance


def test_same_key_same_plan_different_key_different_samples(small_config):
    problem = build_problem(load_scene("dense-snapshot"), small_config.basis)
    a = plan(problem, small_config, key=jax.random.PRNGKey(7))
    b = plan(problem, small_config, key=jax.random.PRNGKey(7))
    c = plan(problem, small_config, key=jax.random.PRNGKey(8))
    np.testing.assert_array_equal(a.setpoints, b.setpoints)
    assert not np.allclose(a.first.setpoints, c.first.setpoints)
    # Every sampler iteration draws fresh samples (the key advances inside the call).
    assert not np.allclose(a.first.setpoints, a.last.setpoints)


def test_warm_start_and_dense_snapshot_is_collision_free(small_config, solve_graphs):
    scene = load_scene("dense-snapshot")
    problem = build_problem(scene, small_config.basis)
    first = plan(problem, small_config, key=jax.random.PRNGKey(0), x_offset=scene.ego.x)
    second = plan(problem, small_config, key=jax.random.PRNGKey(1), warm_start=first.mean, x_offset=scene.ego.x)
    for result in (first, second):
        assert result.status == PlanStatus.SUCCESS
        assert not collides(result.trajectory, scene)
    # A call without a warm start is one with an absent one: the same graph (one compilation) and the same result.
    absent = plan(problem, small_config, key=jax.random.PRNGKey(0), warm_start=WarmStart.absent(), x_offset=scene.ego.x)
    assert len(solve_graphs) == 3 and len(set(solve_graphs)) == 1
    for a, b in zip(jax.tree_util.tree_leaves(first), jax.tree_util.tree_leaves(absent), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(ProblemError, match="warm_start"):
        plan(problem, small_config, key=jax.random.PRNGKey(1), warm_start=np.zeros(5))


def boxed_in_scene() -> Scene:
    ego = EgoState(x=0.0, y=4.0, vx=15.0)
    cars = (Neighbour(x=6.0, y=4.0), Neighbour(x=-6.0, y=4.0, vx=15.0), Neighbour(x=0.0, y=0.5), Neighbour(x=0.0, y=7.5))
    return Scene(ego=ego, road=Road(num_lanes=3), neighbours=cars)


def test_boxed_in_returns_infeasible_and_a_braking_fallback(small_config):
    scene = boxed_in_scene()
    result = plan(build_problem(scene, small_config.basis), small_config, key=jax.random.PRNGKey(0))
    assert result.status == PlanStatus.INFEASIBLE
    assert "fallback" in result.message
    fb = result.fallback
    for arr in (*fb, *result.trajectory, result.coeffs, result.setpoints):
        assert np.all(np.isfinite(arr))
    assert np.all(np.isfinite(list(result.residuals.values()))) and np.all(np.isfinite(list(result.costs.values())))
    assert fb.speed[-1] < fb.speed[0] - 5.0  # brakes
    assert np.abs(fb.y - 4.0).max() < 0.5  # keeps its lane centre
    assert result.safe_trajectory is fb
    assert result.fallback_residual >= 0


def test_non_finite_and_wrong_shape_input_raise(small_config):
    problem = build_problem(load_scene("static-blockage"), small_config.basis)
    with pytest.raises(ProblemError, match="NaN"):
        plan(problem._replace(init_x=jnp.array([0.0, jnp.nan, 0.0])), small_config, key=jax.random.PRNGKey(0))
    with pytest.raises(ProblemError, match="shape"):
        plan(problem._replace(obstacle_x=problem.obstacle_x[:, :50]), small_config, key=jax.random.PRNGKey(0))
    with pytest.raises(ProblemError, match="finite"):
        EgoState(x=0.0, y=float("inf"), vx=1.0)
    with pytest.raises(ProblemError):
        Road(num_lanes=0)


vehicle = st.builds(
    Neighbour,
    x=st.floats(-60, 120), y=st.floats(-1.5, 13.5), vx=st.floats(0, 30), vy=st.floats(-1, 1),
    length=st.floats(3.5, 12.0), width=st.floats(1.5, 2.6),
)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    ego_y=st.floats(-1.0, 13.0), ego_v=st.floats(0.0, 30.0), ego_vy=st.floats(-2, 2), ego_a=st.floats(-5, 5),
    neighbours=st.lists(vehicle, max_size=14), v_des=st.floats(0.0, 35.0), curvature=st.floats(-0.02, 0.02),
)
def test_random_problems_give_finite_well_shaped_results(small_config, ego_y, ego_v, ego_vy, ego_a, neighbours, v_des, curvature):
    scene = Scene(
        ego=EgoState(x=0.0, y=ego_y, vx=ego_v, vy=ego_vy, ax=ego_a),
        road=Road(num_lanes=4, curvature=curvature),
        neighbours=tuple(neighbours),
        v_des=v_des,
    )
    result = plan(build_problem(scene, small_config.basis), small_config, key=jax.random.PRNGKey(0))
    K, n = small_config.basis.num_nodes, small_config.basis.num_coeffs
    assert result.coeffs.shape == (2 * n,) and result.setpoints.shape == (8,)
    for arr in (*result.trajectory, *result.fallback, result.coeffs, result.setpoints, result.mean):
        assert np.all(np.isfinite(arr))
    assert result.trajectory.x.shape == (K,)
    assert all(np.isfinite(v) for v in (*result.residuals.values(), *result.costs.values()))
    assert result.status in (PlanStatus.SUCCESS, PlanStatus.INFEASIBLE)
    if result.status == PlanStatus.SUCCESS:
        assert result.residuals["total"] <= small_config.sampler.residual_tolerance + 1e-6


@pytest.mark.parametrize("lanes, side", [(3, 1), (5, -1), (2, 1)])
def test_off_road_start_plans_back_onto_the_road(small_config, lanes, side):
    """An ego 1.5 m beyond the lane bounds (drifting outward) still gets a feasible plan, and it re-enters
    the road within the recovery time and stays there; without the recovery nothing is feasible."""
    road = Road(num_lanes=lanes, curvature=0.0)
    probe = Scene(ego=EgoState(x=0.0, y=0.0, vx=10.0), road=road)
    lo, hi = probe.lateral_bounds
    y0 = hi + 1.5 if side > 0 else lo - 1.5
    scene = Scene(ego=EgoState(x=0.0, y=y0, vx=10.0, vy=0.3 * side), road=road)
    problem = build_problem(scene, small_config.basis)
    result = plan(problem, small_config, key=jax.random.PRNGKey(0))
    assert result.status == PlanStatus.SUCCESS
    traj = result.trajectory
    back = traj.t >= small_config.projection.recovery_time
    assert np.all((traj.y[back] >= lo - 0.05) & (traj.y[back] <= hi + 0.05)), "the plan must be back on the road"
    # every plan starts at y0, 1.5 m beyond bounds that nothing relaxes without the recovery: none is feasible
    never_relaxed = small_config.replace(projection={"recovery_time": 0.0})
    model = make_model(small_config.basis, small_config.qp)
    strict = constraint_residuals(model, problem, jnp.asarray(result.coeffs)[None], never_relaxed.projection)
    assert float(strict.lane[0]) > small_config.sampler.residual_tolerance


@pytest.mark.parametrize("x_offset, needle", [
    (float("nan"), "x_offset must be finite, got nan"),
    (float("inf"), "x_offset must be finite, got inf"),
    (1e39, r"x_offset must be within \[-100000, 100000\] m, got 1e\+39"),
    (-2e5, r"x_offset must be within \[-100000, 100000\] m"),
    (10**400, "x_offset must be finite"),
    ("5", "x_offset must be a real number"),
    (True, "x_offset must be a real number"),
    ([1.0], "x_offset must be a real number"),
    (np.zeros(3), "x_offset must be a real number"),
    (None, "x_offset must be a real number"),
])
def test_a_bad_x_offset_is_a_one_line_problem_error(small_config, x_offset, needle):
    problem = build_problem(load_scene("static-blockage"), small_config.basis)
    with pytest.raises(ProblemError, match=needle) as exc:
        plan(problem, small_config, key=jax.random.PRNGKey(0), x_offset=x_offset)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("key, needle", [
    (0, "key must be a JAX PRNG key .* got 0"),
    ([0, 0], r"got \[0, 0\]"),
    (np.zeros(2, np.int32), "got ndarray of shape \\(2,\\) and dtype int32"),
    (jnp.zeros(3, jnp.uint32), "shape \\(3,\\)"),
    (jax.random.split(jax.random.PRNGKey(0), 4), "shape \\(4, 2\\)"),
    (jax.random.split(jax.random.key(0), 4), "key must be one PRNG key, got a batch of shape \\(4,\\)"),
    ("seed", "got 'seed'"),
])
def test_a_bad_key_is_a_one_line_problem_error(small_config, key, needle):
    problem = build_problem(load_scene("static-blockage"), small_config.basis)
    with pytest.raises(ProblemError, match=needle) as exc:
        plan(problem, small_config, key=key)
    assert "\n" not in str(exc.value)


def test_typed_keys_numpy_keys_and_real_offsets_plan(small_config):
    """What the checks accept: jax.random.key, a (2,) uint32 array of numpy, an int or a numpy float as x_offset."""
    problem = build_problem(load_scene("static-blockage"), small_config.basis)
    reference = plan(problem, small_config, key=jax.random.PRNGKey(3), x_offset=100.0)
    same = plan(problem, small_config, key=np.asarray(jax.random.PRNGKey(3)), x_offset=np.float32(100.0))
    np.testing.assert_array_equal(same.trajectory.x, reference.trajectory.x)
    assert plan(problem, small_config, key=jax.random.key(3), x_offset=-100000).x_offset == -100000.0
