"""Batch projection: each constraint family enforced where only it binds, convergence, modes."""

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from driveopt.basis import basis_at, derivative_control_points
from driveopt.config import ProjectionConfig, QPConfig
from driveopt.problem import build_problem
from driveopt.projection import (
    road_curvature_at,
    _fast_rsqrt,
    _fast_sqrt,
    _operators,
    _pair,
    constraint_residuals,
    kkt_inverse,
    lane_constraint,
    obstacle_floor,
    obstacle_row_nodes,
    project,
    quasi_definite_inverse,
)
from driveopt.qp import boundary_values, make_model, solve_setpoint_qp
from driveopt.scene import CURVATURE_CELL, CURVATURE_CELLS, EgoState, Neighbour, Road, Scene, load_scene
from driveopt.trajectory import evaluate
from driveopt.xla import XLA_CPU_COMPILER_OPTIONS, supported_compiler_options

MODEL = make_model()
# Everything "off" except what a test turns on.
LOOSE = ProjectionConfig(max_iterations=300, tolerance=0.0, v_max=60.0, a_max=100.0, kappa_max=0.0, centripetal_max=100.0,
                         course_max=0.0)


def setup(scene: Scene, setpoints, qp=QPConfig()):
    problem = build_problem(scene)
    b_x, b_y = boundary_values(problem.init_x, problem.init_y, qp)
    target = solve_setpoint_qp(MODEL, jnp.asarray(setpoints, jnp.float32), b_x, b_y)
    return problem, target, b_x, b_y


def empty_scene(**ego):
    defaults = dict(x=0.0, y=4.0, vx=10.0)
    return Scene(ego=EgoState(**{**defaults, **ego}), road=Road(num_lanes=4, curvature=0.0))


def check_boundary(problem, coeffs):
    traj = evaluate(MODEL, coeffs)
    np.testing.assert_allclose(traj.x[:, 0], problem.init_x[0], atol=1e-3)
    np.testing.assert_allclose(traj.vx[:, 0], problem.init_x[1], atol=1e-3)
    np.testing.assert_allclose(traj.y[:, 0], problem.init_y[0], atol=1e-3)


def test_obstacle_only():
    scene = dataclasses.replace(empty_scene(), neighbours=(Neighbour(x=30.0, y=4.0),))
    problem, target, b_x, b_y = setup(scene, [[10.0] * 4 + [4.0] * 4])
    before = constraint_residuals(MODEL, problem, target, LOOSE)
    assert float(before.obstacle[0]) > 1.0  # the QP drives straight into the stopped car
    out = project(MODEL, problem, target, b_x, b_y, LOOSE)
    traj = evaluate(MODEL, out.coeffs)
    ratio = np.sqrt(((traj.x - problem.obstacle_x[0]) / problem.obstacle_a[0]) ** 2 + ((traj.y - problem.obstacle_y[0]) / problem.obstacle_b[0]) ** 2)
    assert ratio.min() > 0.97
    assert float(out.residuals.obstacle[0]) < 0.3
    check_boundary(problem, out.coeffs)


def _ratios(problem, traj, i=0):
    return np.sqrt(((traj.x - problem.obstacle_x[i]) / problem.obstacle_a[i]) ** 2
                   + ((traj.y - problem.obstacle_y[i]) / problem.obstacle_b[i]) ** 2)


def test_a_car_starting_inside_an_ellipse_may_leave_it_but_not_go_deeper():
    """Stopped beside and just behind a stopped car in the next lane, inside its ellipse (ratio 0.96) but not
    touching it: driving on is feasible (the floor of the constraint rises from 0.96 to 1 over the recovery time);
    without the recovery no plan is, and a plan creeping into the car is not."""
    scene = dataclasses.replace(empty_scene(y=4.0, vx=0.0), neighbours=(Neighbour(x=-4.0, y=1.5),))
    problem, target, b_x, b_y = setup(scene, [[6.0] * 4 + [4.0] * 4])
    r0 = float(_ratios(problem, evaluate(MODEL, target))[0, 0])
    assert 0.9 < r0 < 1.0
    floor = np.asarray(obstacle_floor(MODEL, problem, LOOSE))
    assert floor[0, 0] == pytest.approx(r0, abs=1e-5) and np.all(np.diff(floor[0]) >= 0) and floor[0, -1] == 1.0
    assert np.all(floor[1:] == 1.0)  # the absent (masked) obstacles keep the plain constraint
    leave = project(MODEL, problem, target, b_x, b_y, LOOSE)
    assert float(leave.residuals.total[0]) < 1e-2
    stuck = project(MODEL, problem, target, b_x, b_y, dataclasses.replace(LOOSE, recovery_time=0.0))
    assert float(stuck.residuals.obstacle[0]) > 0.1
    _, deeper, b_x, b_y = setup(scene, [[0.5] * 4 + [1.5] * 4])  # creeping sideways into the stopped car
    assert _ratios(problem, evaluate(MODEL, deeper))[0].min() < 0.8
    out = project(MODEL, problem, deeper, b_x, b_y, LOOSE)
    assert float(out.residuals.obstacle[0]) > 0.1  # the projection pushes it back out, but not within the floor
    assert np.all(_ratios(problem, evaluate(MODEL, out.coeffs))[0] > 0.9)


def test_velocity_only():
    problem, target, b_x, b_y = setup(empty_scene(vx=25.0), [[38.0] * 4 + [4.0] * 4])
    cfg = dataclasses.replace(LOOSE, v_max=30.0)
    assert evaluate(MODEL, target).speed.max() > 35.0
    out = project(MODEL, problem, target, b_x, b_y, cfg)
    assert float(evaluate(MODEL, out.coeffs).speed.max()) < 30.3
    check_boundary(problem, out.coeffs)


def test_acceleration_only():
    problem, target, b_x, b_y = setup(empty_scene(vx=10.0), [[25.0] * 4 + [4.0] * 4])
    cfg = dataclasses.replace(LOOSE, a_max=2.0, rho_acceleration=30.0)
    traj0 = evaluate(MODEL, target)
    assert float(jnp.hypot(traj0.ax, traj0.ay).max()) > 5.0
    out = project(MODEL, problem, target, b_x, b_y, cfg)
    traj = evaluate(MODEL, out.coeffs)
    assert float(jnp.hypot(traj.ax, traj.ay).max()) < 2.0 * 1.1


def test_curvature_only():
    # A fast lateral move at crawling speed bends the path sharply.
    problem, target, b_x, b_y = setup(empty_scene(vx=4.0), [[4.0] * 4 + [10.0] * 4])
    cfg = dataclasses.replace(LOOSE, kappa_max=0.05, rho_velocity=30.0, rho_acceleration=30.0)
    assert float(jnp.abs(evaluate(MODEL, target).curvature).max()) > 0.1
    out = project(MODEL, problem, target, b_x, b_y, cfg)
    assert float(jnp.abs(evaluate(MODEL, out.coeffs).curvature).max()) < 0.05 * 1.1
    check_boundary(problem, out.coeffs)


def road_lateral_acceleration(traj, curvature) -> np.ndarray:
    """[m/s^2] the lateral acceleration a road of constant ``curvature`` [1/m] gives a plan's car: at offset y from the
    reference line it moves at (1 - k y) x' on a path of curvature k / (1 - k y)."""
    vx, y = np.asarray(traj.vx), np.asarray(traj.y)
    return vx * vx * abs(curvature) * (1.0 - curvature * y)


def test_centripetal_only():
    scene = dataclasses.replace(empty_scene(vx=9.0), road=Road(num_lanes=4, curvature=0.01))
    problem, target, b_x, b_y = setup(scene, [[20.0] * 4 + [4.0] * 4])
    cfg = dataclasses.replace(LOOSE, centripetal_max=1.0)  # x'^2 * 0.01 * (1 - 0.01 y) <= 1: about 10 m/s
    assert float(evaluate(MODEL, target).speed.max()) > 15.0
    out = project(MODEL, problem, target, b_x, b_y, cfg)
    assert road_lateral_acceleration(evaluate(MODEL, out.coeffs), 0.01).max() < 1.0 * 1.1
    # The same road with zero curvature leaves the speed alone.
    flat = project(MODEL, problem._replace(road_curvature=jnp.zeros_like(problem.road_curvature)), target, b_x, b_y, cfg)
    assert float(evaluate(MODEL, flat.coeffs).speed.max()) > 15.0


def test_lane_only():
    problem, target, b_x, b_y = setup(empty_scene(y=8.0), [[15.0] * 4 + [16.0] * 4])
    assert float(evaluate(MODEL, target).y.max()) > float(problem.y_ub) + 1.0
    out = project(MODEL, problem, target, b_x, b_y, LOOSE)
    assert float(evaluate(MODEL, out.coeffs).y.max()) < float(problem.y_ub) + 0.05
    assert float(out.residuals.lane[0]) < 0.05
    check_boundary(problem, out.coeffs)


def course(traj):
    """[rad] |angle between the velocity and the road| at every node."""
    return np.abs(np.arctan2(np.asarray(traj.vy), np.asarray(traj.vx)))


def test_course_only():
    # A lane change at 8 m/s: the set-point QP's path leaves the lane at up to ~0.47 rad to the road.
    problem, target, b_x, b_y = setup(empty_scene(vx=8.0, y=4.0), [[8.0] * 4 + [8.0] * 4])
    assert course(evaluate(MODEL, target)).max() > 0.4
    cfg = dataclasses.replace(LOOSE, course_max=0.25)
    assert float(constraint_residuals(MODEL, problem, target, cfg).velocity[0]) > 1.0
    out = project(MODEL, problem, target, b_x, b_y, cfg)
    traj = evaluate(MODEL, out.coeffs)
    assert course(traj)[:, 1:].max() < 0.25 + 0.01
    assert float(out.residuals.velocity[0]) < 0.05
    assert abs(float(traj.y[0, -1]) - 8.0) < 0.5  # it still ends in the target lane
    check_boundary(problem, out.coeffs)
    # Without the bound (P1) the same projection leaves the path as steep as it was.
    free = evaluate(MODEL, project(MODEL, problem, target, b_x, b_y, LOOSE).coeffs)
    assert course(free).max() > 0.4


def test_a_car_turned_across_the_road_plans_its_way_back_within_the_course_bound():
    """Course 0.8 rad now (bound 0.35): the bound starts at the car's course and narrows to 0.35 by the recovery
    time, so a plan that straightens out is feasible; without the recovery no plan is."""
    heading = 0.8
    ego = dict(vx=6.0 * np.cos(heading), vy=6.0 * np.sin(heading), y=2.0)
    problem, target, b_x, b_y = setup(empty_scene(**ego), [[6.0] * 4 + [4.0] * 4])
    cfg = dataclasses.replace(LOOSE, a_max=4.5, course_max=0.35, recovery_time=3.0)
    out = project(MODEL, problem, target, b_x, b_y, cfg)
    traj = evaluate(MODEL, out.coeffs)
    assert float(out.residuals.velocity[0]) < 0.1
    after = np.asarray(MODEL.t) >= cfg.recovery_time
    assert course(traj)[0][after].max() < 0.35 + 0.01
    check_boundary(problem, out.coeffs)
    never_relaxed = project(MODEL, problem, target, b_x, b_y, dataclasses.replace(cfg, recovery_time=0.0))
    assert float(never_relaxed.residuals.velocity[0]) > 0.5


def test_a_crawling_car_is_held_to_the_course_bound_only_above_course_min_speed():
    """A 2 m lateral move from 0.5 m/s. With the default ``course_min_speed`` (1 m/s, as the curvature bound) the
    nodes below it are held only to a right angle (never backwards), and the projection settles on a path that moves
    sideways at a crawl (course up to pi/2) with no residual: the diagonal crawls seen in P2's traffic. With 0.1 m/s
    every node moving faster than that keeps within the bound, and the move is mostly given up."""
    problem, target, b_x, b_y = setup(empty_scene(vx=0.5, y=4.0), [[0.5] * 4 + [6.0] * 4])
    bounded = dataclasses.replace(LOOSE, course_max=0.35)
    loose = project(MODEL, problem, target, b_x, b_y, bounded)
    crawl = course(evaluate(MODEL, loose.coeffs))
    assert float(loose.residuals.velocity[0]) < 0.05 and 1.5 < crawl.max() < np.pi / 2 + 0.01
    held = project(MODEL, problem, target, b_x, b_y, dataclasses.replace(bounded, course_min_speed=0.1))
    traj = evaluate(MODEL, held.coeffs)
    moving = np.hypot(np.asarray(traj.vx), np.asarray(traj.vy))[0] > 0.1
    assert float(held.residuals.velocity[0]) < 0.05
    assert course(traj)[0][moving].max() < 0.35 + 0.05
    assert float(traj.y[0, -1]) < 5.0
    check_boundary(problem, held.coeffs)


@pytest.mark.parametrize("vx0, speed_setpoint", [(2.0, -3.0), (-2.0, 3.0)])
def test_no_node_moves_against_the_direction_of_travel(vx0, speed_setpoint):
    """Set-points that turn the motion round (a forward car told to reverse, a reversing one told to drive forwards):
    with the course bound, the projected plan keeps every node's velocity within a right angle of the direction of
    travel (at a crawl too), so it stops instead; without it (P1) the plan turns round with no residual."""
    problem, target, b_x, b_y = setup(empty_scene(vx=vx0, y=4.0), [[speed_setpoint] * 4 + [4.0] * 4])
    direction = np.sign(vx0)
    assert (direction * np.asarray(evaluate(MODEL, target).vx)).min() < -2.0
    bounded = dataclasses.replace(LOOSE, course_max=0.35)
    assert float(constraint_residuals(MODEL, problem, target, bounded).velocity[0]) > 1.0
    out = project(MODEL, problem, target, b_x, b_y, bounded)
    traj = evaluate(MODEL, out.coeffs)
    assert float(out.residuals.velocity[0]) < 0.05
    assert (direction * np.asarray(traj.vx)).min() > -0.05
    check_boundary(problem, out.coeffs)
    free = project(MODEL, problem, target, b_x, b_y, LOOSE)
    assert float(free.residuals.velocity[0]) < 0.05
    assert (direction * np.asarray(evaluate(MODEL, free.coeffs).vx)).min() < -2.0


@pytest.fixture(scope="module")
def dense_batch():
    problem = build_problem(load_scene("dense-snapshot"))
    key = jax.random.PRNGKey(3)
    p = jnp.concatenate([16 + 4 * jax.random.normal(key, (300, 4)), 6 + 4 * jax.random.normal(jax.random.fold_in(key, 1), (300, 4))], 1)
    b_x, b_y = boundary_values(problem.init_x, problem.init_y, QPConfig())
    return problem, solve_setpoint_qp(MODEL, p, b_x, b_y), b_x, b_y


def test_residuals_fall_with_iterations(dense_batch):
    problem, target, b_x, b_y = dense_batch
    medians = []
    for iters in (1, 10, 50):
        out = project(MODEL, problem, target, b_x, b_y, ProjectionConfig(max_iterations=iters, tolerance=0.0))
        medians.append(float(jnp.median(out.residuals.total)))
        assert np.all(np.isfinite(np.asarray(out.coeffs)))
    assert medians[0] > medians[1] > medians[2]
    assert medians[2] < 0.5 * medians[0]


def test_barrier_with_unit_gamma_equals_plain(dense_batch):
    problem, target, b_x, b_y = dense_batch
    plain = project(MODEL, problem, target, b_x, b_y, ProjectionConfig(max_iterations=15, tolerance=0.0))
    barrier = project(MODEL, problem, target, b_x, b_y, ProjectionConfig(max_iterations=15, tolerance=0.0, barrier=True), gamma_obs=1.0, gamma_lane=1.0)
    np.testing.assert_allclose(barrier.coeffs, plain.coeffs, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(barrier.residuals.total, plain.residuals.total, rtol=1e-4, atol=1e-3)


def test_lane_barrier_limits_the_approach_rate():
    """With gamma < 1 the distance to the lane bound shrinks at most by (1 - gamma) per node."""
    problem, target, b_x, b_y = setup(empty_scene(y=4.0), [[15.0] * 4 + [16.0] * 4])
    gamma = 0.1
    # with the lateral start acceleration free the sample turns harder at first: more iterations to converge
    cfg = dataclasses.replace(LOOSE, barrier=True, rho_lane=30.0, max_iterations=1000)
    out = project(MODEL, problem, target, b_x, b_y, cfg, gamma_lane=gamma)
    gap = float(problem.y_ub) - np.asarray(evaluate(MODEL, out.coeffs).y[0])
    assert np.all(gap[1:] >= (1 - gamma) * gap[:-1] - 0.05)
    plain = project(MODEL, problem, target, b_x, b_y, LOOSE)
    gap_plain = float(problem.y_ub) - np.asarray(evaluate(MODEL, plain.coeffs).y[0])
    assert np.any(gap_plain[1:] < (1 - gamma) * gap_plain[:-1] - 0.05)  # plain mode approaches faster


@pytest.mark.parametrize("course_max, rtol, atol", [(0.0, 1e-5, 1e-4), (0.35, 1e-3, 1e-2)])
def test_unrolled_equals_early_stopping_loop(dense_batch, course_max, rtol, atol):
    """The same iterations either way. With the course bound, a node whose velocity sits on the bound switches
    branch on float-order differences between the two compiled loops, so those agree to 1e-3 rather than 1e-5."""
    problem, target, b_x, b_y = dense_batch
    cfg = ProjectionConfig(max_iterations=12, tolerance=0.0, course_max=course_max)
    loop = jax.jit(lambda t: project(MODEL, problem, t, b_x, b_y, cfg))(target)
    scan = jax.jit(lambda t: project(MODEL, problem, t, b_x, b_y, cfg, unroll=True))(target)
    assert int(loop.iterations) == int(scan.iterations) == 12
    np.testing.assert_allclose(loop.coeffs, scan.coeffs, rtol=rtol, atol=atol)


def test_anderson_early_stopping_loop_equals_the_unrolled_one(dense_batch):
    """Anderson's memory written slot by slot in the early-stopping loop and in the unrolled one: the same
    iterations, also when the count is not a multiple of the window (10 of 3)."""
    problem, target, b_x, b_y = dense_batch
    cfg = ProjectionConfig(max_iterations=10, tolerance=0.0, anderson_window=3)
    loop = jax.jit(lambda t: project(MODEL, problem, t, b_x, b_y, cfg))(target)
    scan = jax.jit(lambda t: project(MODEL, problem, t, b_x, b_y, cfg, unroll=True))(target)
    assert int(loop.iterations) == int(scan.iterations) == 10
    np.testing.assert_allclose(loop.coeffs, scan.coeffs, rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("unroll", [False, True], ids=["loop", "unrolled"])
@pytest.mark.parametrize("window", [0, 4], ids=["plain", "anderson"])
def test_a_traced_iteration_count_runs_as_many_iterations_as_that_static_count(dense_batch, unroll, window):
    """One compiled projection of at most 12 iterations told to run 5 gives what a projection compiled for 5 gives (to
    1e-3: a node whose velocity sits on the course bound switches branch on float-order differences between two
    compiled loops, as in test_projection's loop against its unrolled form)."""
    problem, target, b_x, b_y = dense_batch
    cfg = ProjectionConfig(max_iterations=12, tolerance=0.0, anderson_window=window)
    traced = jax.jit(lambda t, k: project(MODEL, problem, t, b_x, b_y, cfg, unroll=unroll, iterations=k))(target, 5)
    static = jax.jit(lambda t: project(MODEL, problem, t, b_x, b_y, dataclasses.replace(cfg, max_iterations=5),
                                       unroll=unroll))(target)
    full = jax.jit(lambda t: project(MODEL, problem, t, b_x, b_y, cfg, unroll=unroll))(target)
    assert int(traced.iterations) == int(static.iterations) == 5 and int(full.iterations) == 12
    np.testing.assert_allclose(traced.coeffs, static.coeffs, rtol=1e-3, atol=1e-2)
    np.testing.assert_allclose(traced.residuals.total, static.residuals.total, rtol=1e-3, atol=1e-2)
    assert not np.allclose(np.asarray(traced.coeffs), np.asarray(full.coeffs), atol=1e-1)


def test_early_stop_on_a_feasible_batch():
    problem, target, b_x, b_y = setup(empty_scene(), [[12.0] * 4 + [4.0] * 4] * 4)
    out = project(MODEL, problem, target, b_x, b_y, ProjectionConfig(max_iterations=50, tolerance=1e-3))
    assert int(out.iterations) < 50 and int(out.status) == 0
    np.testing.assert_allclose(out.coeffs, target, atol=1e-2)  # nothing to correct


def test_unrolled_projection_is_differentiable(dense_batch):
    problem, target, b_x, b_y = dense_batch
    cfg = ProjectionConfig(max_iterations=5, tolerance=0.0, barrier=True)

    def loss(target, gamma):
        out = project(MODEL, problem, target, b_x, b_y, cfg, gamma_obs=gamma, gamma_lane=gamma, unroll=True)
        return jnp.sum(out.residuals.total) + jnp.sum((out.coeffs - target) ** 2)

    g_target, g_gamma = jax.grad(loss, argnums=(0, 1))(target[:32], 0.9)
    assert np.all(np.isfinite(np.asarray(g_target))) and np.isfinite(float(g_gamma))
    assert float(jnp.abs(g_target).max()) > 0 and abs(float(g_gamma)) > 0


def test_fast_rsqrt_matches_rsqrt_and_its_derivative():
    x = jnp.logspace(-12, 12, 20001, dtype=jnp.float32)
    np.testing.assert_allclose(_fast_rsqrt(x), jax.lax.rsqrt(x), rtol=1e-5)
    np.testing.assert_allclose(jax.vmap(jax.grad(_fast_rsqrt))(x), -0.5 * x ** -1.5, rtol=1e-4)
    assert np.all(np.isfinite(np.asarray(_fast_rsqrt(jnp.array([0.0, jnp.inf])))))  # clipped, never inf/nan


def test_fast_sqrt_matches_sqrt_and_is_flat_at_zero():
    x = jnp.logspace(-11, 12, 20001, dtype=jnp.float32)
    np.testing.assert_allclose(_fast_sqrt(x), jnp.sqrt(x), rtol=1e-5)
    assert float(_fast_sqrt(jnp.float32(0.0))) == 0.0 and float(jax.grad(_fast_sqrt)(jnp.float32(0.0))) == 0.0


def test_paired_arrays_come_back_exactly():
    # _pair packs two arrays so that XLA computes them in one loop: the parts must be the inputs, bit for bit, for
    # finite values of any magnitude and either sign of the run-time one's source
    rng = np.random.default_rng(0)
    x, y = (rng.standard_normal(100_000) * 10.0 ** rng.integers(-30, 30, 100_000) for _ in range(2))
    x, y = x.astype(np.float32), y.astype(np.float32)
    paired = jax.jit(lambda x, y, s: _pair(x, y, jax.lax.complex(jnp.abs(s), 0.0 * s)))
    for direction in (1.0, -1.0):
        px, py = paired(x, y, jnp.float32(direction))
        np.testing.assert_array_equal(np.asarray(px), x)
        np.testing.assert_array_equal(np.asarray(py), y)


def test_barrier_lane_rows_match_dense_rows():
    """The node-space lane rows (no matrix) agree with the dense rows G of lane_constraint for gamma < 1."""
    problem, target, b_x, b_y = setup(empty_scene(y=8.0), [[15.0] * 4 + [16.0] * 4, [10.0] * 4 + [-2.0] * 4])
    cfg = dataclasses.replace(LOOSE, barrier=True, max_iterations=1)
    gamma = 0.3
    out = project(MODEL, problem, target, b_x, b_y, cfg, gamma_lane=gamma)
    G, e = lane_constraint(MODEL, problem.y_lb, problem.y_ub, gamma, True)
    c_y = np.asarray(out.coeffs[:, MODEL.W.shape[1]:], np.float64)
    violation = np.maximum(c_y @ np.asarray(G, np.float64).T - np.asarray(e), 0.0)  # distance of each row to its bound
    # the reference in float64 on the host: an accelerator's default matrix product (TF32) is not one
    np.testing.assert_allclose(out.residuals.lane, np.sqrt(np.sum(violation**2, axis=1)), rtol=1e-4, atol=1e-4)


def test_cpu_compiler_options_keep_results(dense_batch):
    """The options the planner compiles with are accepted and change only rounding."""
    problem, target, b_x, b_y = dense_batch
    cfg = ProjectionConfig(max_iterations=1, tolerance=0.0)  # more iterations amplify rounding (the clips are not smooth)
    run = lambda t: project(MODEL, problem, t, b_x, b_y, cfg)  # noqa: E731
    plain = jax.jit(run)(target)
    options = supported_compiler_options(XLA_CPU_COMPILER_OPTIONS)
    tuned = jax.jit(run, compiler_options=options)(target)
    np.testing.assert_allclose(tuned.residuals.total, plain.residuals.total, rtol=1e-3, atol=1e-2)


def test_unknown_compiler_options_are_dropped():
    options = {"xla_cpu_prefer_vector_width": 256, "xla_cpu_no_such_option": True}
    assert supported_compiler_options(options) == {"xla_cpu_prefer_vector_width": 256}


def test_quasi_definite_inverse_matches_a_pivoting_inverse():
    """Gauss-Jordan without pivoting inverts [[H, A'], [A, 0]] (H positive definite, A full row rank) as LU with
    pivoting does, in float32, for random matrices and for the planner's own ill-conditioned y-axis KKT matrices."""
    rng = np.random.default_rng(0)
    n, m, B = 11, 3, 64
    X = rng.normal(size=(B, n, n))
    H = X @ X.transpose(0, 2, 1) + 0.1 * np.eye(n)
    A = np.asarray(MODEL.A_y, np.float64)
    W = np.asarray(MODEL.W, np.float64)
    planner_H = np.eye(n) + 1e3 * (W.T @ W) + np.linspace(0.0, 1e3, B)[:, None, None] * (W[1:].T @ W[1:])
    for hessians in (H, planner_H):
        kkt = np.block([[hessians, np.broadcast_to(A.T, (B, n, m))], [np.broadcast_to(A, (B, m, n)), np.zeros((B, m, m))]])
        reference = np.linalg.inv(kkt)
        ours = np.asarray(quasi_definite_inverse(jnp.asarray(kkt, jnp.float32)), np.float64)
        lu = np.asarray(jnp.linalg.inv(jnp.asarray(kkt, jnp.float32)), np.float64)
        # the rows the projection uses (coefficients): within a few times float32 LU's error of the float64 inverse
        error, lu_error = (np.abs(x[:, :n] - reference[:, :n]).max() for x in (ours, lu))
        assert error <= 4.0 * lu_error
    with pytest.raises(AssertionError):  # it is not a general inverse: a zero leading pivot breaks it
        bad = np.array([[[0.0, 1.0], [1.0, 0.0]]], np.float32)
        np.testing.assert_allclose(quasi_definite_inverse(jnp.asarray(bad)), np.linalg.inv(bad), atol=1e-3)


def test_the_kkt_inverse_is_lapacks_for_one_matrix_and_the_vectorised_one_for_a_vmapped_batch():
    """A planning call inverts its KKT matrices with LAPACK as before (bit-identical); a loss vmapped over training rows
    gets no LAPACK call at all (a batched LU's triangular solves can deadlock XLA's CPU thread pool), with the same
    inverse and gradient within float32 accuracy."""
    rng = np.random.default_rng(1)
    n, m, B = 11, 3, 8
    X = rng.normal(size=(B, n, n))
    A = np.asarray(MODEL.A_y, np.float64)
    kkt = np.block([[X @ X.transpose(0, 2, 1) + np.eye(n), np.broadcast_to(A.T, (B, n, m))],
                    [np.broadcast_to(A, (B, m, n)), np.zeros((B, m, m))]])
    matrices = jnp.asarray(kkt, jnp.float32)
    np.testing.assert_array_equal(kkt_inverse(matrices[0]), jnp.linalg.inv(matrices[0]))
    assert "lapack" in jax.jit(kkt_inverse).lower(matrices[0]).as_text()
    assert "lapack" not in jax.jit(jax.vmap(kkt_inverse)).lower(matrices).as_text()
    np.testing.assert_allclose(jax.vmap(kkt_inverse)(matrices), np.linalg.inv(kkt), atol=1e-4)

    def loss(inverse):
        return lambda matrix: jnp.sum(jnp.sin(inverse(matrix)) * jnp.arange(n + m))

    reference = jax.vmap(jax.grad(loss(jnp.linalg.inv)))(matrices)
    for gradient in (jax.vmap(jax.grad(loss(kkt_inverse)))(matrices),
                     jnp.stack([jax.grad(loss(kkt_inverse))(matrix) for matrix in matrices])):
        np.testing.assert_allclose(gradient, reference, rtol=1e-3, atol=1e-3 * float(jnp.abs(reference).max()))


# Anderson acceleration and over-relaxation (projection.anderson_window, projection.relaxation; off by default).
_ACCELERATION_PROBLEMS = ("dense-snapshot", "slow-leader-four-lane", "slow-leader-three-lane", "static-blockage")
_PROJECT = jax.jit(lambda problem, target, b_x, b_y, cfg: project(MODEL, problem, target, b_x, b_y, cfg), static_argnums=4)
_SAMPLES = 64


def _random_batch(name: str, seed: int):
    problem = build_problem(load_scene(name))
    key = jax.random.PRNGKey(seed)
    p = jnp.concatenate([16 + 4 * jax.random.normal(key, (_SAMPLES, 4)),
                         6 + 4 * jax.random.normal(jax.random.fold_in(key, 1), (_SAMPLES, 4))], 1)
    b_x, b_y = boundary_values(problem.init_x, problem.init_y, QPConfig())
    return problem, solve_setpoint_qp(MODEL, p, b_x, b_y), b_x, b_y


def test_acceleration_is_off_by_default_and_its_loop_without_a_window_is_the_plain_iteration():
    """Off (the defaults) the plain loop runs (its results bit for bit as before the setting existed: checked when it
    was added, on plans and projections of the built-in problems). The accelerated loop with no window and a relaxation
    a hair below 1 does the plain iteration's arithmetic, scaled by 1 - 2^-20: its bookkeeping (which point is
    evaluated, which coefficients and multipliers come back, the iteration count) is the plain loop's."""
    assert ProjectionConfig().anderson_window == 0 and ProjectionConfig().relaxation == 1.0
    problem, target, b_x, b_y = _random_batch("dense-snapshot", 0)
    cfg = ProjectionConfig(max_iterations=20, tolerance=0.0)
    plain = _PROJECT(problem, target, b_x, b_y, cfg)
    loop = _PROJECT(problem, target, b_x, b_y, dataclasses.replace(cfg, relaxation=1.0 - 2.0 ** -20))
    assert int(loop.iterations) == 20
    np.testing.assert_allclose(loop.coeffs, plain.coeffs, rtol=1e-3, atol=1e-2)
    np.testing.assert_allclose(loop.multipliers, plain.multipliers, rtol=1e-3, atol=1e-1)
    np.testing.assert_allclose(loop.residuals.total, plain.residuals.total, rtol=1e-3, atol=1e-2)


@pytest.mark.slow  # bilevel's projection, Anderson's with control points, is checked in the default suite (below)
@pytest.mark.parametrize("name", _ACCELERATION_PROBLEMS)
def test_anderson_leaves_residuals_no_worse_than_the_plain_iteration(name):
    """After 20 iterations, for two batches of 64 random set-point trajectories per built-in problem: with a window of 4
    the mean and median constraint residual are no worse than the plain loop's (by more than 2 % + 0.01) and the p90 by
    no more than 10 % + 0.05 (measured on 12 batches of 100: mean and median lower on every one, by 10-98 %; p90 at
    most 0.3 % higher); every coefficient is finite and the equality rows hold."""
    cfg = ProjectionConfig(max_iterations=20, tolerance=0.0)
    for seed in (0, 1):
        problem, target, b_x, b_y = _random_batch(name, seed)
        plain = np.asarray(_PROJECT(problem, target, b_x, b_y, cfg).residuals.total)
        out = _PROJECT(problem, target, b_x, b_y, dataclasses.replace(cfg, anderson_window=4))
        fast = np.asarray(out.residuals.total)
        assert np.all(np.isfinite(np.asarray(out.coeffs))) and np.all(np.isfinite(fast))
        assert int(out.iterations) == 20
        check_boundary(problem, out.coeffs)
        assert fast.mean() <= 1.02 * plain.mean() + 0.01
        assert np.median(fast) <= 1.02 * np.median(plain) + 0.01
        assert np.percentile(fast, 90) <= 1.1 * np.percentile(plain, 90) + 0.05


@pytest.mark.slow
def test_over_relaxation_stays_finite_and_anderson_stops_early_on_a_feasible_batch():
    """Relaxation 1.5: finite, mean residual within 25 % of the plain loop's (measured: 17 % higher to 33 % lower on 12
    batches). With a window, the early stop still ends a feasible batch's loop."""
    problem, target, b_x, b_y = _random_batch("static-blockage", 2)
    cfg = ProjectionConfig(max_iterations=20, tolerance=0.0)
    plain = np.asarray(_PROJECT(problem, target, b_x, b_y, cfg).residuals.total)
    out = _PROJECT(problem, target, b_x, b_y, dataclasses.replace(cfg, relaxation=1.5))
    total = np.asarray(out.residuals.total)
    assert np.all(np.isfinite(np.asarray(out.coeffs))) and np.all(np.isfinite(total))
    assert total.mean() <= 1.25 * plain.mean()
    problem, target, b_x, b_y = setup(empty_scene(), [[12.0] * 4 + [4.0] * 4] * _SAMPLES)
    out = _PROJECT(problem, target, b_x, b_y, ProjectionConfig(max_iterations=20, tolerance=1e-3, anderson_window=4))
    assert int(out.iterations) < 20 and int(out.status) == 0
    np.testing.assert_allclose(out.coeffs, target, atol=1e-2)


@pytest.mark.slow  # a minute of compiling on two loaded cores
def test_unrolled_anderson_is_differentiable(dense_batch):
    problem, target, b_x, b_y = dense_batch
    cfg = ProjectionConfig(max_iterations=5, tolerance=0.0, anderson_window=3)

    def loss(target):
        out = project(MODEL, problem, target, b_x, b_y, cfg, unroll=True)
        return jnp.sum(out.residuals.total) + jnp.sum((out.coeffs - target) ** 2)

    grad = jax.grad(loss)(target[:16])
    assert np.all(np.isfinite(np.asarray(grad))) and float(jnp.abs(grad).max()) > 0


# Velocity and acceleration rows at the Bernstein control points (projection.derivative_bounds; "nodes" by default).
_CONTROL_POINTS = ProjectionConfig(max_iterations=20, tolerance=0.0, derivative_bounds="control_points")


def _control_point_magnitudes(coeffs, pieces):
    """Largest speed [m/s] and acceleration [m/s^2] control point of each trajectory (B, 2n) on ``pieces`` pieces."""
    velocity, acceleration = derivative_control_points(MODEL.W.shape[1] - 1, float(MODEL.t[-1]), pieces)
    c = np.asarray(coeffs, np.float64).reshape(coeffs.shape[0], 2, -1)
    return tuple(np.hypot(*(c @ points.T).transpose(1, 0, 2)).max(axis=1) for points in (velocity, acceleration))


@pytest.mark.slow  # settings that are off by default: compiles the projection with them (10-30 s each)
def test_control_point_rows_are_off_by_default_and_residuals_are_still_measured_at_the_nodes():
    """Off by default (off, every plan and projection is bit for bit as before the setting existed: checked when it was
    added, on the plans of a 250-sample and a barrier planner and on plain, early-stopping, unrolled, per-sample-gamma and
    Anderson projections of the built-in problems). On, the residuals a projection reports are those of its result at
    the nodes, the plain rows' (``constraint_residuals``), so that the two settings compare on the same measure."""
    assert ProjectionConfig().derivative_bounds == "nodes"
    problem, target, b_x, b_y = _random_batch("dense-snapshot", 0)
    out = _PROJECT(problem, target, b_x, b_y, _CONTROL_POINTS)
    assert np.all(np.isfinite(np.asarray(out.coeffs))) and int(out.iterations) == 20
    check_boundary(problem, out.coeffs)
    at_nodes = constraint_residuals(MODEL, problem, out.coeffs, dataclasses.replace(_CONTROL_POINTS, derivative_bounds="nodes"))
    for reported, measured in zip(out.residuals, at_nodes):
        np.testing.assert_allclose(reported, measured, rtol=1e-4, atol=1e-4)
    np.testing.assert_array_equal(np.asarray(constraint_residuals(MODEL, problem, out.coeffs, _CONTROL_POINTS).total),
                                  np.asarray(at_nodes.total))


def test_control_points_within_the_bounds_keep_speed_and_acceleration_within_them_at_every_node():
    """Tight bounds (v_max 20 m/s, a_max 5 m/s^2) on a free road, starting at 18 m/s, with speed set-points around 22 m/s
    (no target within the bounds at its control points): after 200 iterations, the samples whose velocity and
    acceleration control points all meet the bounds to 0.01 (the projection's remaining violation) have every node's
    speed and acceleration within them to 0.01, and so do the values on a 10x finer grid (convex hull); that is most of
    the batch (measured: 59 of 64; 24 to 0.001, the loop converging slowly onto such tight bounds)."""
    rng = np.random.default_rng(0).normal(size=(_SAMPLES, 8))
    problem, target, b_x, b_y = setup(empty_scene(vx=18.0), np.concatenate([22.0 + 3.0 * rng[:, :4], 4.0 + rng[:, 4:]], 1))
    cfg = dataclasses.replace(_CONTROL_POINTS, v_max=20.0, a_max=5.0, max_iterations=200)
    slack = 0.01  # [m/s], [m/s^2]
    speed_cp, acc_cp = _control_point_magnitudes(target, cfg.derivative_pieces)
    assert not np.any((speed_cp <= cfg.v_max + slack) & (acc_cp <= cfg.a_max + slack))
    out = _PROJECT(problem, target, b_x, b_y, cfg)
    speed_cp, acc_cp = _control_point_magnitudes(out.coeffs, cfg.derivative_pieces)
    held = (speed_cp <= cfg.v_max + slack) & (acc_cp <= cfg.a_max + slack)
    assert held.mean() >= 0.8
    horizon, n = float(MODEL.t[-1]), MODEL.W.shape[1]
    fine = basis_at(n - 1, horizon, np.linspace(0.0, horizon, 10 * MODEL.W.shape[0]))
    c = np.asarray(out.coeffs, np.float64)[held].reshape(-1, 2, n)
    for grid in (np.asarray(MODEL.Wd, np.float64), fine.Wd):
        assert np.hypot(*(c @ grid.T).transpose(1, 0, 2)).max() <= cfg.v_max + slack
    for grid in (np.asarray(MODEL.Wdd, np.float64), fine.Wdd):
        assert np.hypot(*(c @ grid.T).transpose(1, 0, 2)).max() <= cfg.a_max + slack


@pytest.mark.parametrize("name", [_ACCELERATION_PROBLEMS[0]] + [pytest.param(name, marks=pytest.mark.slow)
                                                                 for name in _ACCELERATION_PROBLEMS[1:]])
def test_control_point_rows_leave_residuals_about_as_low_as_the_plain_ones(name):
    """After 20 iterations, two batches of 64 random set-point trajectories per built-in problem, control points on 4
    pieces: the residuals at the nodes stay close to the plain rows': mean within 1.1x + 0.05 and p90 within 1.3x + 0.1
    (measured on 16 batches, seeds 0-3: mean 0.70-1.05x, lower on 13; p90 0.54-1.22x). The median is not bounded: on
    slow-leader-four-lane it rose on all four batches (0.06-0.36 -> 0.26-0.60), most rows there being near 0 either way."""
    for seed in (0, 1):
        problem, target, b_x, b_y = _random_batch(name, seed)
        plain = np.asarray(_PROJECT(problem, target, b_x, b_y, dataclasses.replace(_CONTROL_POINTS,
                                                                                    derivative_bounds="nodes")).residuals.total)
        out = _PROJECT(problem, target, b_x, b_y, _CONTROL_POINTS)
        total = np.asarray(out.residuals.total)
        assert np.all(np.isfinite(np.asarray(out.coeffs))) and np.all(np.isfinite(total))
        check_boundary(problem, out.coeffs)
        assert total.mean() <= 1.1 * plain.mean() + 0.05
        assert np.percentile(total, 90) <= 1.3 * np.percentile(plain, 90) + 0.1


# Rows of the nearest obstacles only (projection.nearest_obstacles; 0, every obstacle, by default), chosen per sample or
# for the whole batch (projection.nearest_choice).
@pytest.mark.slow  # settings that are off by default: compiles the projection with them (10-30 s each)
@pytest.mark.parametrize("choice", ["sample", "batch"])
def test_nearest_obstacles_keep_k_rows_per_node_and_report_every_obstacle(choice):
    """Off by default (off, plans and projections bit for bit as before: checked when it was added, as for
    derivative_bounds). With k = 4 of dense-snapshot's 10 neighbours, the KKT matrix holds 4 obstacle rows per node
    (the plain one with rho_obstacle x 4/10), the reported residuals are those of the result against every obstacle, and
    with k at least the number of real obstacles (static-blockage: 2 of 10 slots) the projection is the plain one."""
    assert (ProjectionConfig().nearest_obstacles, ProjectionConfig().nearest_choice) == (0, "sample")
    cfg = ProjectionConfig(max_iterations=20, tolerance=0.0)
    problem, target, b_x, b_y = _random_batch("dense-snapshot", 0)
    near = dataclasses.replace(cfg, nearest_obstacles=4, nearest_choice=choice)
    scaled = dataclasses.replace(cfg, rho_obstacle=cfg.rho_obstacle * 4 / 10)
    np.testing.assert_allclose(_operators(MODEL, problem, near, 1.0).penalty, _operators(MODEL, problem, scaled, 1.0).penalty,
                               rtol=1e-5)
    out = _PROJECT(problem, target, b_x, b_y, near)
    assert np.all(np.isfinite(np.asarray(out.coeffs)))
    check_boundary(problem, out.coeffs)
    for reported, measured in zip(out.residuals, constraint_residuals(MODEL, problem, out.coeffs, cfg)):
        np.testing.assert_allclose(reported, measured, rtol=1e-4, atol=1e-4)
    problem, target, b_x, b_y = _random_batch("static-blockage", 0)
    assert float(problem.obstacle_mask.sum()) == 2 and problem.obstacle_x.shape[0] == 10
    plain = _PROJECT(problem, target, b_x, b_y, cfg)
    for k in (2, 3):
        changed = dataclasses.replace(cfg, nearest_obstacles=k, nearest_choice=choice)
        np.testing.assert_allclose(_PROJECT(problem, target, b_x, b_y, changed).coeffs, plain.coeffs, rtol=1e-5, atol=1e-4)


def test_the_batchs_nearest_obstacles_are_those_any_sample_comes_nearest_at_each_node():
    """Two samples, three obstacles at each node: the batch's two nearest are the one nearest the first sample and the
    one nearest the second (by ellipse ratio), real obstacles before padding, and their per-node fields come along."""
    from driveopt.projection import _nearest_for_batch, _target_ratios

    problem = build_problem(load_scene("dense-snapshot"))
    K = problem.obstacle_x.shape[1]
    ops = _operators(MODEL, problem, ProjectionConfig(nearest_obstacles=2, nearest_choice="batch"), 1.0)
    ratio = jnp.full((problem.obstacle_x.shape[0], 2, K), 50.0)
    ratio = ratio.at[3, 0].set(2.0).at[7, 1].set(5.0).at[5, 0].set(9.0).at[5, 1].set(6.0)  # 3 and 7 come nearest
    ratio = ratio.at[1, :, :10].set(jnp.inf).at[1, 0, 10:].set(1.0)  # 1 beats 7 from node 10 on
    rows, rows_ops = _nearest_for_batch(problem, ops, ratio, 2)
    first = np.where(np.arange(K) < 10, 3, 1)
    for slot, expected in ((0, first), (1, np.where(np.arange(K) < 10, 7, 3))):
        np.testing.assert_array_equal(rows.obstacle_x[slot], np.asarray(problem.obstacle_x)[expected, np.arange(K)])
        np.testing.assert_array_equal(rows.obstacle_a[slot], np.asarray(problem.obstacle_a)[expected])
        np.testing.assert_array_equal(rows_ops.obstacle_floor[slot], np.asarray(ops.obstacle_floor)[expected, np.arange(K)])
        np.testing.assert_array_equal(rows_ops.inverse_axes[:, slot],
                                      np.asarray(ops.inverse_axes)[:, expected, np.arange(K)])
    padded = problem._replace(obstacle_mask=problem.obstacle_mask.at[3].set(0.0))
    ratio = _target_ratios(MODEL, padded, jnp.zeros((2, 2, MODEL.W.shape[1])))
    assert np.all(np.isinf(np.asarray(ratio[3]))) and np.all(np.isfinite(np.asarray(ratio[np.asarray(padded.obstacle_mask) > 0])))


@pytest.mark.slow  # settings that are off by default: compiles the projection with them (10-30 s each)
@pytest.mark.parametrize("choice, k, mean_ratio, p90_ratio", [("sample", 4, 1.05, 1.25), ("batch", 5, 1.2, 1.3)])
def test_the_nearest_obstacles_leave_residuals_about_as_low_as_every_obstacle(choice, k, mean_ratio, p90_ratio):
    """dense-snapshot (10 neighbours), 20 iterations, two batches of 64: with the nearest k per node the mean residual
    is within mean_ratio x + 0.05 and the p90 within p90_ratio x + 0.1 of the plain loop's (measured on seeds 0-3: each
    sample's nearest 4, mean 0.90-0.96x, p90 0.96-1.13x; with the nearest 1, mean 1.25-1.57x; the batch's nearest 5,
    mean 1.03-1.15x, p90 1.06-1.25x; the batch's nearest 4, mean 1.07-1.26x, p90 1.11-1.39x)."""
    cfg = ProjectionConfig(max_iterations=20, tolerance=0.0)
    for seed in (0, 1):
        problem, target, b_x, b_y = _random_batch("dense-snapshot", seed)
        plain = np.asarray(_PROJECT(problem, target, b_x, b_y, cfg).residuals.total)
        near = dataclasses.replace(cfg, nearest_obstacles=k, nearest_choice=choice)
        total = np.asarray(_PROJECT(problem, target, b_x, b_y, near).residuals.total)
        assert np.all(np.isfinite(total))
        assert total.mean() <= mean_ratio * plain.mean() + 0.05
        assert np.percentile(total, 90) <= p90_ratio * np.percentile(plain, 90) + 0.1


# Obstacle rows at fewer nodes later in the plan (projection.obstacle_stride; 1, every node, by default).
def test_obstacle_rows_keep_every_node_early_then_every_strideth_and_the_last():
    t = np.asarray(MODEL.t)  # 100 nodes over 15 s
    np.testing.assert_array_equal(obstacle_row_nodes(t, ProjectionConfig()), np.arange(100))
    nodes = obstacle_row_nodes(t, ProjectionConfig(obstacle_stride=4, obstacle_dense_time=3.0))
    dense = np.flatnonzero(t <= 3.0)
    np.testing.assert_array_equal(nodes[:dense.size], dense)
    np.testing.assert_array_equal(np.diff(nodes[dense.size - 1:]), 4)  # nodes 19, 23, ..., 99
    assert nodes[-1] == 99 and nodes.size == 40
    uneven = obstacle_row_nodes(t, ProjectionConfig(obstacle_stride=7, obstacle_dense_time=0.0))
    assert uneven[0] == 0 and uneven[-1] == 99 and np.all(np.diff(uneven) <= 7)
    assert _operators(MODEL, build_problem(load_scene("dense-snapshot")), ProjectionConfig(), 1.0).obstacle_nodes is None


def test_a_nodes_ellipse_grows_by_the_relative_motion_over_the_nodes_left_out():
    """Rows at nodes 0, 1, 5 (gaps 1 and 4): the ego moves 9 m from node 1 to node 5 and the obstacle 1 m, so the
    ellipses there grow by the 3 of those 4 nodes' relative motion (8 m) a row no longer covers, halved: 8 x 3 / 8 = 3 m;
    node 0, whose neighbour is the next node, not at all; an obstacle moving with the ego not at all."""
    from driveopt.projection import _motion_growth, _obstacle_nodes, _steps

    spread = _obstacle_nodes(jnp.asarray(MODEL.W), jnp.ones(100), np.array([0, 1, 5])).spread
    np.testing.assert_allclose(spread, [[0.0, 0.0, 3 / 8], [0.0, 3 / 8, 0.0]])
    ego = _steps(jnp.array([[0.0, 2.0, 11.0]]))  # (2, 1, 3)
    obstacles = _steps(jnp.array([[30.0, 30.0, 31.0], [30.0, 32.0, 41.0]]))  # (2, 2, 3)
    np.testing.assert_allclose(_motion_growth(ego, obstacles, 0, spread), [[0.0, 3.0, 3.0]])
    np.testing.assert_allclose(_motion_growth(ego, obstacles, 1, spread), [[0.0, 0.0, 0.0]])


@pytest.mark.parametrize("stride", [4, pytest.param(8, marks=pytest.mark.slow)])
def test_sparse_obstacle_rows_keep_a_fast_pass_clear_of_a_stopped_car_at_every_node(stride):
    """A stopped car 60 m ahead in the ego's lane, passed at 20 m/s: between rows 4 or 8 nodes (0.6-1.2 s, 12-24 m)
    apart the ego would jump past most of the ellipse (15 m long), but grown by that motion the rows keep every node,
    those without rows too, outside it; the residual is measured at every node."""
    scene = dataclasses.replace(empty_scene(vx=20.0), neighbours=(Neighbour(x=60.0, y=4.0, vx=0.0),))
    problem, target, b_x, b_y = setup(scene, [[20.0] * 4 + [4.0] * 4])
    cfg = dataclasses.replace(LOOSE, obstacle_stride=stride, obstacle_dense_time=0.0)
    assert float(constraint_residuals(MODEL, problem, target, cfg).obstacle[0]) > 1.0
    out = project(MODEL, problem, target, b_x, b_y, cfg)
    traj = evaluate(MODEL, out.coeffs)
    assert _ratios(problem, traj).min() > 0.97
    assert float(out.residuals.obstacle[0]) < 0.3
    check_boundary(problem, out.coeffs)


# The registered bilevel's projection (fewer iterations, accelerated, control-point bounds) on recorded closed-loop
# states: tests/core/closed-loop-states.npz holds 16 planning problems bilevel faced in closed loop (8 each on
# four-lane-d3.0 and two-lane-d2.5, every 40th step of one episode; benchmarks/perf/settings_offline.py wrote them).
_STATES = Path(__file__).with_name("closed-loop-states.npz")


def _recorded_batches(seed: int):
    """Per recorded state: the problem, 64 set-point QP targets (speeds the current one +- 4 m/s, random lane centres)
    and the boundary values."""
    from benchmarks.perf.settings_offline import load_states  # the writer of the file reads it

    for index, (_, problem) in enumerate(load_states(_STATES)):
        problem = jax.tree_util.tree_map(jnp.asarray, problem)
        key = jax.random.PRNGKey(100 * seed + index)
        speeds = jnp.clip(problem.init_x[1] + 4 * jax.random.normal(key, (_SAMPLES, 4)), 0.0, 30.0)
        lanes = problem.lane_center0 + problem.lane_width * jax.random.randint(jax.random.fold_in(key, 1), (_SAMPLES, 4), 0,
                                                                               int(problem.num_lanes))
        b_x, b_y = boundary_values(problem.init_x, problem.init_y, QPConfig())
        yield problem, solve_setpoint_qp(MODEL, jnp.concatenate([speeds, lanes], 1), b_x, b_y), b_x, b_y


def _recorded_residuals(reference: ProjectionConfig, changed: ProjectionConfig) -> tuple[np.ndarray, np.ndarray]:
    """The total residuals of the recorded batches (seed 0, pooled) after each projection; every coefficient of the
    changed one finite and its equality rows held."""
    totals: tuple[list, list] = ([], [])
    for problem, target, b_x, b_y in _recorded_batches(seed=0):
        totals[0].append(np.asarray(_PROJECT(problem, target, b_x, b_y, reference).residuals.total))
        out = _PROJECT(problem, target, b_x, b_y, changed)
        assert np.all(np.isfinite(np.asarray(out.coeffs)))
        check_boundary(problem, out.coeffs)
        totals[1].append(np.asarray(out.residuals.total))
    return np.concatenate(totals[0]), np.concatenate(totals[1])


@pytest.mark.parametrize("extra", [{}, pytest.param({"obstacle_stride": 4}, marks=pytest.mark.slow)],
                         ids=["realtime", "obstacle-stride-4"])  # the stride is off by default: its check runs with -m slow
def test_the_realtime_projection_leaves_recorded_states_residuals_about_as_low_as_twenty_plain_iterations(extra):
    """12 iterations, Anderson window 4, bounds at the control points on 4 pieces (and with ``extra``: obstacle rows at
    every 4th node after 3 s), against the plain 20 iterations, on the 16 recorded states (64 random set-point rows each,
    pooled): mean residual within 1.15x, median within 1.1x + 0.05, p90 within 1.25x (measured with seeds 0 and 1: mean
    1.085x and 1.076x, median 1.015x and 0.987x, p90 1.163x and 1.162x; with the obstacle stride mean 1.117x and 1.115x,
    median 1.065x and 1.043x, p90 1.189x and 1.169x, and rows below 0.05 9.3 % and 9.1 % against the plain 9.0 % and
    8.4 %). Every coefficient finite and the equality rows held."""
    from driveopt.registry import REALTIME_PROJECTION

    plain = ProjectionConfig()
    before, after = _recorded_residuals(plain, dataclasses.replace(plain, **{**REALTIME_PROJECTION, **extra}))
    assert after.mean() <= 1.15 * before.mean()
    assert np.median(after) <= 1.1 * np.median(before) + 0.05
    assert np.percentile(after, 90) <= 1.25 * np.percentile(before, 90)


def test_vqvae_filters_pass_leaves_most_recorded_rows_as_feasible_as_p2s_hundred_plain_iterations():
    """``vqvae-filter``'s pass (``registry.VQVAE_FILTER_PROJECTION``: 60 iterations accelerated, the bounds at the
    control points; here the barrier with the plain filter's parameters) against P2's pass (100 plain iterations at
    the nodes, ``vqvae``'s), on the 16 recorded states (64 random set-point rows each, pooled): at least 0.8x as many
    rows within the sampler's residual tolerance (0.05) and the mean residual within 1.6x (measured with seeds 0 and
    1: 0.87x and 0.85x, 1.51x and 1.50x). The shorter pass projects a batch less far than P2's; the pipeline keeps
    its 150 lowest rows of 1000, and whether it drives as well is the closed-loop check's
    (docs/results/speed.md#p2s-one-pass-accelerated)."""
    from driveopt.registry import get_optimiser

    ours, p2s = (get_optimiser(name).config.projection for name in ("vqvae-filter", "vqvae"))
    assert (p2s.max_iterations, ours.max_iterations, ours.anderson_window) == (100, 60, 4) and ours.barrier
    assert dataclasses.replace(ours, max_iterations=100, anderson_window=0, derivative_bounds="nodes") == p2s
    before, after = _recorded_residuals(p2s, ours)
    assert np.mean(after < 0.05) >= 0.8 * np.mean(before < 0.05)
    assert after.mean() <= 1.6 * before.mean()


def test_centripetal_bound_reads_the_curvature_where_each_node_is():
    """A curve from 40 m on (0.04 1/m, 1 m/s^2: at most 5 m/s there): the plan keeps its speed before the curve and
    slows to the curve's speed by the time it is in it, where a constant bound would slow the whole plan."""
    cells = tuple(0.0 if i * CURVATURE_CELL < 40.0 else 0.04 for i in range(CURVATURE_CELLS))
    scene = dataclasses.replace(empty_scene(vx=10.0), road=Road(num_lanes=4, curvature_ahead=cells))
    problem, target, b_x, b_y = setup(scene, [[10.0] * 4 + [4.0] * 4])
    cfg = dataclasses.replace(LOOSE, centripetal_max=1.0)
    traj = evaluate(MODEL, project(MODEL, problem, target, b_x, b_y, cfg).coeffs)
    x, speed = np.asarray(traj.x)[0], np.asarray(traj.speed)[0]
    assert x.max() > 45.0  # the plan reaches the curve
    assert road_lateral_acceleration(traj, 0.04)[0][x >= 40.0 + CURVATURE_CELL].max() < 1.0 * 1.1
    assert speed[x < 10.0].min() > 8.0  # not slowed from the start


def test_a_car_faster_than_a_curves_speed_plans_its_way_down_to_it_by_the_recovery_time():
    """At 12 m/s on a curve whose speed is 10 m/s (0.01 1/m, 1 m/s^2): the bound starts at the car's speed and
    narrows to the curve's by the recovery time, so a plan that slows is feasible and within the bound from then on;
    without the recovery no plan is (the first rows already exceed it). A car below the curve's speed is held to it
    as before."""
    scene = dataclasses.replace(empty_scene(vx=12.0), road=Road(num_lanes=4, curvature=0.01))
    problem, target, b_x, b_y = setup(scene, [[10.0] * 4 + [4.0] * 4])
    cfg = dataclasses.replace(LOOSE, a_max=4.5, centripetal_max=1.0, recovery_time=3.0)
    out = project(MODEL, problem, target, b_x, b_y, cfg)
    lateral = road_lateral_acceleration(evaluate(MODEL, out.coeffs), 0.01)[0]
    assert float(out.residuals.velocity[0]) < 0.05
    assert lateral[np.asarray(MODEL.t) >= cfg.recovery_time].max() < 1.0 * 1.02
    check_boundary(problem, out.coeffs)
    never_relaxed = project(MODEL, problem, target, b_x, b_y, dataclasses.replace(cfg, recovery_time=0.0))
    assert float(never_relaxed.residuals.velocity[0]) > 0.3
    slower = setup(dataclasses.replace(scene, ego=EgoState(x=0.0, y=4.0, vx=9.0)), [[20.0] * 4 + [4.0] * 4])
    held = evaluate(MODEL, project(MODEL, *slower, cfg).coeffs)
    assert road_lateral_acceleration(held, 0.01).max() < 1.0 * 1.04


def test_the_centripetal_bound_holds_the_cars_own_lateral_acceleration_beside_the_reference_line():
    """A car held in the lane 12 m beside the reference line of a 50 m curve (1 m/s^2 bound) drives a 38 m circle on
    the inside (its speed 0.76 times the plan's rate) and a 62 m one on the outside (1.24 times), wherever the line
    lies in y (``Road.curvature_origin``). Its lateral
    acceleration, from the plan's nodes placed on those circles in the world and differentiated there (independent of
    the frame's formula), reaches the bound and stays within it on both sides: bounding the rate as on the reference
    line would give at most 0.76 and 1.24 m/s^2."""
    cfg = dataclasses.replace(LOOSE, centripetal_max=1.0)
    dt = float(MODEL.t[1] - MODEL.t[0])
    for curvature, line in ((0.02, 0.0), (-0.02, 0.0), (0.02, 100.0)):  # the line at y = 100 m: lanes from there
        road = Road(num_lanes=4, first_lane_center=line, curvature=curvature, curvature_origin=line)
        problem, target, b_x, b_y = setup(Scene(ego=EgoState(x=0.0, y=line + 12.0, vx=6.0), road=road),
                                          [[10.0] * 4 + [line + 12.0] * 4])
        traj = evaluate(MODEL, project(MODEL, problem, target, b_x, b_y, cfg).coeffs)
        x, y = np.asarray(traj.x, float)[0], np.asarray(traj.y, float)[0] - line
        radius = 1.0 / curvature  # signed: the centre at (0, radius) in the frame of the line's start
        angle = x / radius
        world = np.stack([(radius - y) * np.sin(angle), radius - (radius - y) * np.cos(angle)])
        velocity, acceleration = np.gradient(world, dt, axis=1), np.gradient(np.gradient(world, dt, axis=1), dt, axis=1)
        lateral = np.abs(velocity[0] * acceleration[1] - velocity[1] * acceleration[0]) / np.hypot(*velocity)
        inner = lateral[5:-5]  # the differences' ends are one-sided
        assert 0.9 < inner.max() < 1.0 * 1.1


@pytest.mark.parametrize("where", ["nodes", "control_points"])
def test_with_acceleration_recovery_a_car_braking_beyond_the_bound_plans_its_way_back_within_it(where):
    """Braking at 5.8 m/s^2 with a 5 m/s^2 bound (the closed loop caps the bound at the car's limit, and a plan starts
    at the car's acceleration): every plan's first rows exceed the bound, the projection cannot remove that, and the
    plan stays infeasible; with ``acceleration_recovery`` the bound starts at 5.8 and narrows to 5 by the recovery
    time, so the plan is feasible and within 5 m/s^2 from then on. Off, it is the plain bound."""
    scene = Scene(ego=EgoState(x=0.0, y=4.0, vx=15.0, ax=-5.8), road=Road(num_lanes=4))
    problem, target, b_x, b_y = setup(scene, [[10.0] * 4 + [4.0] * 4])
    cfg = dataclasses.replace(LOOSE, a_max=5.0, recovery_time=3.0, derivative_bounds=where)
    stuck = project(MODEL, problem, target, b_x, b_y, cfg)
    assert float(stuck.residuals.acceleration[0]) > 0.5
    out = project(MODEL, problem, target, b_x, b_y, dataclasses.replace(cfg, acceleration_recovery=True))
    assert float(out.residuals.acceleration[0]) < 0.05
    acceleration = np.hypot(np.asarray(evaluate(MODEL, out.coeffs).ax)[0], np.asarray(evaluate(MODEL, out.coeffs).ay)[0])
    assert acceleration[np.asarray(MODEL.t) >= cfg.recovery_time].max() < 5.0 * 1.01
    check_boundary(problem, out.coeffs)


def test_road_curvature_at_reads_the_cell_of_each_position():
    cells = jnp.arange(CURVATURE_CELLS, dtype=jnp.float32) * 1e-3
    x = jnp.array([-3.0, 0.0, CURVATURE_CELL * 0.99, CURVATURE_CELL * 1.01, CURVATURE_CELL * 10.5, 1e4])
    assert np.allclose(road_curvature_at(cells, x), [0.0, 0.0, 0.0, 1e-3, 1e-2, (CURVATURE_CELLS - 1) * 1e-3])
