"""Planner registry and the baseline proposal distributions."""

import dataclasses
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from driveopt import EgoState, Neighbour, PlanStatus, Road, Scene, faithful
from driveopt.config import QPConfig
from driveopt.drivers.optimiser import DRIVEOPT_LOOP, PAPERS_LOOP, ClosedLoop, OptimiserSpec
from driveopt.errors import UnknownNameError
from driveopt.faithful import P1_RANKING_COST_WEIGHT
from driveopt.fallback import Fallback
from driveopt.method import DRIVEOPT_METHOD, PAPERS_FALLBACK, Method
from driveopt.planner import goal_from_setpoints, plan
from driveopt.priors.grids import GoalGridPrior, GridPrior
from driveopt.priors.p1_authors import (
    BatchGoals,
    FixedGaussian,
    LearnedStart,
    SpeedOffsetGrid,
    VanillaGuesses,
    lateral_noise_factor,
    spread_indices,
)
from driveopt.problem import build_problem
from driveopt.qp import boundary_values, make_model, solve_setpoint_qp
from driveopt.drivers.commands import P2_AUTHORS_COMMAND
from driveopt.ranking import CostPlusResidual, FeasibilityFirst, P1AuthorsRanking, P2AuthorsRanking
from driveopt.row_sharing import EveryRow
from driveopt.registry import (P2_PASS_PROJECTION, REALTIME_SAMPLES, VQVAE_FILTER_PROJECTION, get_optimiser,
                               get_planner, list_planners, planner_rows)
from driveopt.scene import load_scene
from driveopt.trajectory import evaluate


def test_registry_names_and_clear_error():
    assert {"bilevel", "random", "grid", "vanilla", "batch", "idm"} <= set(list_planners())
    assert {"random-p1", "grid-p1", "vanilla-p1", "batch-p1"} <= set(list_planners())
    with pytest.raises(UnknownNameError, match="valid planners: bilevel"):
        get_planner("nope")
    with pytest.raises(UnknownNameError, match="optimisers: bilevel"):
        get_optimiser("idm")
    assert get_optimiser("grid") is get_planner("grid")


def test_every_row_builds_its_spec_once_with_the_rows_name_and_description():
    """The descriptions live in the rows; a factory's spec carries its row's, and is built once; every planner outside
    the references runs the optimiser."""
    assert [row.name for row in planner_rows()] == list_planners()
    for row in planner_rows():
        spec = get_planner(row.name)
        assert (spec.name, spec.description) == (row.name, row.description)
        assert get_planner(row.name) is spec
        assert isinstance(spec, OptimiserSpec) == spec.is_optimiser == (row.family != "reference"), row.name


def test_a_planner_is_built_only_when_asked_for():
    """Importing the registry builds nothing; asking for grid-p1 builds it and grid (its base), and loads no Flax."""
    code = ("import sys\nfrom driveopt import registry\nbefore = registry._built.cache_info().currsize\n"
            "registry.get_planner('grid-p1')\n"
            "print(before, registry._built.cache_info().currsize, 'flax' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["0", "2", "False"]


def test_batch_size_override_caps_elites_and_keeps_vanilla_single():
    bilevel = get_planner("bilevel").with_samples(60).config.sampler
    assert (bilevel.num_samples, bilevel.num_constraint_elites, bilevel.num_elites) == (60, 60, 40)
    assert get_planner("vanilla").with_samples(250).config.sampler.num_samples == 1  # one sample is the method
    assert get_planner("grid").with_samples(None) == get_planner("grid")
    assert get_planner("idm").with_samples(250) == get_planner("idm")


def test_the_default_planner_plans_the_real_time_sample_count_and_the_readme_says_so():
    """bilevel's samples per iteration, which drive, bench, plan and Controller use unless told otherwise, are the
    real-time count (its measurement: docs/results/speed.md), and the README and the configuration reference state it."""
    from pathlib import Path

    from driveopt.controller import Controller

    sampler = get_planner("bilevel").config.sampler
    assert (sampler.num_samples, sampler.num_constraint_elites, sampler.num_elites) == (REALTIME_SAMPLES, 100, 40)
    assert Controller().spec.config.sampler.num_samples == REALTIME_SAMPLES
    root = Path(__file__).parents[2]
    assert f"run `bilevel` at {REALTIME_SAMPLES} samples per iteration by default" in (root / "README.md").read_text()
    assert f"the registered `bilevel` plans {REALTIME_SAMPLES}" in (root / "docs" / "configuration.md").read_text()


@pytest.mark.parametrize("name", ["random", "grid", "vanilla", "batch"])
def test_baselines_plan_finite_trajectories(name):
    spec = get_planner(name)  # grid as registered: the configuration tests/cli/test_cli.py's plan compiles too
    scene = load_scene("dense-snapshot")
    result = plan(build_problem(scene, spec.config.basis), spec.config, key=jax.random.PRNGKey(0), prior=spec.prior())
    for arr in (*result.trajectory, result.coeffs, result.setpoints):
        assert np.all(np.isfinite(arr))
    assert result.history.best_score.shape == (1,)  # no adaptation: a single sampler iteration


@pytest.mark.parametrize("name", ["random", "grid", "vanilla", "batch"])
def test_p1_faithful_baselines_differ_only_in_what_p1_did_not_have(name):
    base, p1 = get_optimiser(name), get_optimiser(f"{name}-p1")
    assert p1.config == base.config.replace(sampler={"structured_fraction": 0.0}, qp={"initial_lateral_acceleration": True},
                                            cost={"consistency": 0.0, "slowing": 0.0, "lane_flow": 0.0},
                                            projection={"course_max": 0.0, "ego_turn_rate": 0.0})
    assert base.config.projection.course_max > 0 and base.config.projection.ego_turn_rate > 0
    # the papers' method (ranking, no stop rows, a plain fallback) and loop (the contact guard off, ...)
    assert p1.method == Method(CostPlusResidual(P1_RANKING_COST_WEIGHT), Fallback(straightens=False, evasion=False,
                                                                                  in_batch=False))
    assert base.method == Method(FeasibilityFirst(), Fallback(), EveryRow()) == DRIVEOPT_METHOD
    assert base.loop.contact_guard and not p1.loop.contact_guard
    assert p1.make_prior is base.make_prior and p1.fixed_batch == base.fixed_batch and p1.warm_start == base.warm_start
    assert (p1.loop.executes_infeasible, p1.loop.braking_prediction, p1.loop.replan_every) == (True, False, 5)
    assert (base.loop.executes_infeasible, base.loop.braking_prediction, base.loop.replan_every) == (False, True, 1)
    assert p1.loop == ClosedLoop.papers(replan_every=5) and base.loop == DRIVEOPT_LOOP
    assert p1.description.startswith("P1-faithful")
    assert p1.with_replan_every(1).loop.replan_every == 1  # bench --replan-every still overrides it


@pytest.mark.parametrize("name", ["random", "grid", "vanilla", "batch"])
def test_a_p1_baseline_is_one_replace_of_driveopts(name):
    """Name, description, P1's maths, the papers' method and the papers' loop: nothing else differs."""
    base, p1 = get_optimiser(name), get_optimiser(f"{name}-p1")
    assert p1 == dataclasses.replace(base, name=p1.name, description=p1.description, config=base.config.replace(**faithful.P1_MATHS),
                                     method=base.method.as_papers(CostPlusResidual(P1_RANKING_COST_WEIGHT)),
                                     loop=ClosedLoop.papers(replan_every=5))


@pytest.mark.parametrize("name", ["vqvae", "vqvae-filter", "cvae-filter", "cvae-multipliers"])
def test_a_faithful_pipeline_is_one_replace_of_driveopts(name):
    """P2's pipelines and [5]'s: the same spec with the papers' method (the row sharing kept), the papers' loop and
    the faithful maths; P2's with its authors' command, zero start acceleration and both accelerations imposed."""
    strong, spec = get_optimiser(name), get_optimiser(f"{name}-faithful")
    p2 = name != "cvae-multipliers"
    loop = dataclasses.replace(PAPERS_LOOP, command=P2_AUTHORS_COMMAND, measured_start=False) if p2 else PAPERS_LOOP
    maths = faithful.P2_MATHS if p2 else faithful.FAITHFUL_MATHS
    assert spec == dataclasses.replace(strong, name=spec.name, description=spec.description,
                                       config=strong.config.replace(**maths),
                                       method=strong.method.as_papers(spec.method.ranking), loop=loop)


def test_grid_prior_fills_the_batch_and_changes_lane_from_its_quarter_on():
    scene = Scene(ego=EgoState(x=0.0, y=5.0, vx=10.0), road=Road(num_lanes=4))  # 1 m off the centre at 4 m
    problem = build_problem(scene)
    p = np.asarray(GridPrior().propose(problem, jax.random.PRNGKey(0), 160).samples)
    assert p.shape == (160, 8)
    assert len({tuple(row) for row in np.round(p, 4)}) == 160  # 10 speeds x 4 lanes x 4 quarters, no repeats
    assert np.allclose(p[:, :4], p[:, :1])  # one speed held over the horizon
    np.testing.assert_allclose(np.unique(p[:, 0]), np.linspace(0.0, 30.0, 10), rtol=1e-6)
    assert set(np.round(p[:, 7], 3)) == {0.0, 4.0, 8.0, 12.0}  # every lane is a target, and the plan ends there
    held = []
    for lateral in p[:, 4:]:
        at_target = np.isclose(lateral, lateral[-1])
        assert np.all(np.diff(at_target.astype(int)) >= 0)  # the current position first, then the target to the end
        assert np.allclose(lateral[~at_target], 5.0)
        held.append(int((~at_target).sum()))
    assert set(held) == {0, 1, 2, 3}  # the change in each quarter
    # Two lanes, 250 samples: 31 speeds 1 m/s apart; the 2 rows beyond the whole grid repeat its slowest speed.
    two = build_problem(Scene(ego=EgoState(x=0.0, y=4.0, vx=10.0), road=Road(num_lanes=2)))
    q = np.asarray(GridPrior().propose(two, jax.random.PRNGKey(0), 250).samples)
    np.testing.assert_allclose(np.unique(q[:, 0]), np.arange(31.0), atol=1e-5)
    assert set(np.round(q[:, 7], 3)) == {0.0, 4.0}
    # The same problem always gives the same grid (no randomness).
    np.testing.assert_array_equal(p, np.asarray(GridPrior().propose(problem, jax.random.PRNGKey(5), 160).samples))


def test_grid_creeps_up_a_queue_it_cannot_pass():
    """At rest in a jam (the state of docs/findings/grid-standstill.md, two-lane-d2.5): its own lane queued behind a
    braking car 34.5 m ahead, the other lane flowing at 2-7 m/s. Grid as registered (320 samples, two lanes: 40 speeds
    0.77 m/s apart) creeps up the queue; the ten-speed grid (0, 3.3, 6.7 ... m/s) found only its zero-speed rows
    feasible here, and stood still."""
    queue = (Neighbour(x=34.5, y=4.0, vx=2.5, accel=-1.0), *(Neighbour(x=x, y=4.0) for x in (48.7, 58.2, 67.5, 77.2)))
    flowing = tuple(Neighbour(x=x, y=0.0, vx=v) for x, v in ((21.4, 2.0), (34.4, 3.2), (51.5, 5.7), (73.7, 7.0)))
    scene = Scene(ego=EgoState(x=0.0, y=4.0, vx=0.0), road=Road(num_lanes=2), neighbours=queue + flowing)
    spec = get_planner("grid")  # the configuration test_baselines_plan_finite_trajectories[grid] compiles
    result = plan(build_problem(scene, spec.config.basis), spec.config, key=jax.random.PRNGKey(0), prior=spec.prior())
    assert result.status == PlanStatus.SUCCESS
    assert 0.5 < result.setpoints[0] < 3.3 and np.allclose(result.setpoints[:4], result.setpoints[0])
    assert 10.0 < float(result.trajectory.x[-1]) < 34.5  # moves up, and stays behind the queue


def test_vanilla_leaves_rest_on_an_empty_road():
    """At rest 0.45 m off its lane's centre, nothing ahead: vanilla as registered moves off towards v_des. With v_des
    as the set-point of every quarter its one row asked for 18.8 m/s^2 at the start, and with the centre as the
    first quarter's lateral set-point it moved sideways from rest against the velocity bounds; either way it stayed
    infeasible after the projection, and the car kept its stop row for the rest of the episode."""
    scene = Scene(ego=EgoState(x=0.0, y=4.45, vx=0.0), road=Road(num_lanes=2))
    spec = get_planner("vanilla")  # the configuration test_baselines_plan_finite_trajectories[vanilla] compiles
    problem = build_problem(scene, spec.config.basis)
    speeds = np.asarray(spec.prior().propose(problem, jax.random.PRNGKey(0), 1).samples)[0, :4]
    np.testing.assert_allclose(speeds, [5.0, 10.0, 15.0, float(problem.v_des)])  # v_des, 5 m/s per quarter at most
    result = plan(problem, spec.config, key=jax.random.PRNGKey(0), prior=spec.prior())
    assert result.status == PlanStatus.SUCCESS
    np.testing.assert_allclose(result.setpoints, [*speeds, 4.45, 4.0, 4.0, 4.0], atol=1e-5)  # the row, not a stop row
    assert float(result.trajectory.speed[-1]) > 15.0 and abs(float(result.trajectory.y[-1]) - 4.0) < 0.1
    # at v_des the row is v_des throughout
    cruising = build_problem(Scene(ego=EgoState(x=0.0, y=4.0, vx=float(problem.v_des)), road=Road(num_lanes=2)))
    np.testing.assert_allclose(np.asarray(spec.prior().propose(cruising, jax.random.PRNGKey(0), 1).samples)[0, :4],
                               float(problem.v_des), rtol=1e-6)


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


# ---------------------------------------------------------------------------------------------- faithful planners

P1_FAITHFUL = ("bilevel", "cvae", "random", "grid", "vanilla", "batch")
P2_FAITHFUL = ("vqvae", "vqvae-filter", "cvae-filter")


def test_faithful_planners_are_registered_beside_the_strengthened_ones():
    names = set(list_planners())
    for name in P1_FAITHFUL + P2_FAITHFUL:
        assert {name, f"{name}-faithful"} <= names


@pytest.mark.parametrize("name", P1_FAITHFUL + P2_FAITHFUL)
def test_faithful_planners_have_no_driveopt_machinery_and_replan_every_period(name):
    spec, strong = get_optimiser(f"{name}-faithful"), get_optimiser(name)
    assert isinstance(spec.method.ranking, P1AuthorsRanking if name in P1_FAITHFUL else CostPlusResidual)
    assert spec.method.fallback == Fallback(straightens=False, evasion=False, in_batch=False) == PAPERS_FALLBACK
    assert spec.method.row_sharing == strong.method.row_sharing  # P2's pipelines keep projecting repeated rows once
    p2 = name in P2_FAITHFUL  # P2's pipelines: their authors' command and zero start (P2_MATHS imposes both axes)
    assert spec.loop == (dataclasses.replace(PAPERS_LOOP, command=P2_AUTHORS_COMMAND, measured_start=False) if p2
                         else PAPERS_LOOP)
    assert not spec.loop.contact_guard and spec.loop.executes_infeasible and not spec.loop.braking_prediction
    assert not spec.loop.approach_selection and spec.warm_start == (name in ("bilevel", "cvae"))  # MPC-Bi-Level carries its mean
    # the bi-level optimiser and every baseline plan with one period: the strengthened bilevel's
    assert (spec.loop.replan_every == strong.loop.replan_every == get_optimiser("bilevel").loop.replan_every
            == faithful.AUTHORS_REPLAN_EVERY == 1)
    c = spec.config
    assert (c.sampler.structured_fraction, c.cost.consistency, c.projection.course_max, c.projection.ego_turn_rate) == (0, 0, 0, 0)
    assert c.qp.initial_lateral_acceleration == p2 and spec.description  # P1's lateral start free (FAITHFUL_MATHS)


@pytest.mark.parametrize("name, iterations, projection, elites, weight", [
    ("bilevel", 5, 20, 150, 1e-3),  # the authors' velocity_scaling of each expert_mpc/expert_*.py
    ("cvae", 5, 20, 150, 1e-3),
    ("random", 1, 100, 150, 1e-5),
    ("grid", 1, 100, 150, 1e-2),
    ("vanilla", 1, 100, 300, 1e-5),
    ("batch", 1, 100, 100, 1e-2),  # DiffProj's expert_batch.py (ellite_num_projection 100)
])
def test_p1_faithful_budgets_are_the_authors(name, iterations, projection, elites, weight):
    s = get_optimiser(f"{name}-faithful")
    assert s.config.sampler.num_samples == 1000 and s.config.sampler.num_iterations == iterations
    assert s.config.projection.max_iterations == projection and s.config.sampler.num_constraint_elites == elites
    assert s.config.sampler.num_elites == 50 and s.method.ranking == P1AuthorsRanking(speed_weight=weight)
    assert s.config.qp.terminal_position == (name == "batch")
    assert not s.fixed_batch and s.with_samples(100).config.sampler.num_samples == 100  # --quick can shrink them
    if name in ("grid", "batch", "vanilla"):  # driveopt's versions: a fifth of the iterations, coarser grids, one sample
        assert get_optimiser(f"{name}-p1").config.projection.max_iterations < projection or name == "vanilla"
        assert get_optimiser(f"{name}-p1").config.sampler.num_samples < 1000


def test_the_faithful_grid_is_the_authors_50_speeds_by_20_offsets():
    problem = build_problem(load_scene("dense-snapshot"))
    spec = get_optimiser("grid-faithful")
    prior = spec.prior(4)
    assert isinstance(prior, SpeedOffsetGrid)
    p = np.asarray(prior.propose(problem, jax.random.PRNGKey(0), 1000).samples)
    assert p.shape == (1000, 8) and len({tuple(row) for row in p.round(4)}) == 1000
    np.testing.assert_array_equal(p[:, :4], p[:, :1].repeat(4, axis=1))  # every pair held over the horizon
    np.testing.assert_array_equal(p[:, 4:], p[:, 4:5].repeat(4, axis=1))
    v_des = float(problem.v_des)
    speeds, offsets = np.unique(p[:, 0].round(4)), np.unique(p[:, 4].round(4))
    assert len(speeds) == 50 and len(offsets) == 20
    np.testing.assert_allclose([speeds[0], speeds[-1]], [max(v_des - 16, 0), v_des + 16], atol=1e-4)
    np.testing.assert_allclose([offsets[0], offsets[-1]], [float(problem.y_lb), float(problem.y_ub)], atol=1e-4)
    q = np.asarray(prior.propose(problem, jax.random.PRNGKey(9), 1000).samples)
    np.testing.assert_array_equal(p, q)  # a fixed grid
    fewer = np.asarray(prior.propose(problem, jax.random.PRNGKey(0), 100).samples)
    assert len(np.unique(fewer[:, 4].round(4))) == 20  # a smaller batch keeps evenly spread rows, every offset


def test_the_faithful_batch_goals_are_the_authors_25_speeds_by_40_terminal_positions():
    """DiffProj's expert_mpc/expert_batch.py (compute_projection): a product of 25 speeds on v_des +- 12 m/s and 40
    terminal lateral positions on [y_lb, y_ub], terminal positions outermost, the same for every key."""
    problem = build_problem(load_scene("dense-snapshot"))
    prior = get_optimiser("batch-faithful").prior(4)
    assert isinstance(prior, BatchGoals) and (prior.num_speeds, prior.num_terminal_offsets, prior.speed_spread) == (25, 40, 12.0)
    proposal = prior.propose(problem, jax.random.PRNGKey(0), 1000)
    p = np.asarray(proposal.samples, np.float64)
    assert p.shape == (1000, 8) and len({tuple(row) for row in p.round(4)}) == 1000
    np.testing.assert_array_equal(p[:, :4], p[:, :1].repeat(4, axis=1))  # the goal's speed in every quarter
    np.testing.assert_array_equal(p[:, 4:], p[:, 4:5].repeat(4, axis=1))  # its terminal lateral position likewise
    v_des, y_lb, y_ub = float(problem.v_des), float(problem.y_lb), float(problem.y_ub)
    assert v_des >= 12.0  # no speed raised to 0: the support is the authors'
    speeds = v_des + np.linspace(-12.0, 12.0, 25)
    offsets = np.linspace(y_lb, y_ub, 40)
    np.testing.assert_allclose(p[:, 0], np.tile(speeds, 40), atol=1e-4)  # speeds innermost, as their meshgrid
    np.testing.assert_allclose(p[:, 4], np.repeat(offsets, 25), atol=1e-4)
    # a uniform product: means at the centres, variances (range^2 (n + 1) / (12 (n - 1))), no correlation
    mean, cov = np.asarray(proposal.mean, np.float64), np.asarray(proposal.cov, np.float64)
    np.testing.assert_allclose(mean, [v_des] * 4 + [(y_lb + y_ub) / 2] * 4, atol=1e-4)
    speed_var, offset_var = 24.0**2 * 26 / (12 * 24), (y_ub - y_lb) ** 2 * 41 / (12 * 39)
    assert speed_var == pytest.approx(52.0)
    jitter = np.eye(8) * 1e-3
    expected = np.block([[np.full((4, 4), speed_var), np.zeros((4, 4))], [np.zeros((4, 4)), np.full((4, 4), offset_var)]])
    np.testing.assert_allclose(cov, expected + jitter, rtol=1e-4, atol=1e-3)
    # deterministic: the same goals for every key and every call
    for key in (jax.random.PRNGKey(0), jax.random.PRNGKey(7)):
        np.testing.assert_array_equal(np.asarray(prior.propose(problem, key, 1000).samples), np.asarray(proposal.samples))
    fewer = np.asarray(prior.propose(problem, jax.random.PRNGKey(0), 100).samples)
    assert len(np.unique(fewer[:, 4].round(4))) == 40  # a smaller batch keeps evenly spread goals, every position


def test_the_faithful_batch_qp_imposes_the_terminal_lateral_position_only():
    """expert_batch.py's QP: y(T) = y_f and y'(T) = 0 imposed, no x(T) row; x tracks the goal's speed, y has no
    tracking term. The set-point QP of batch-faithful's configuration does the same."""
    spec = get_optimiser("batch-faithful")
    qp = spec.config.qp
    assert qp.terminal_position and not qp.terminal_longitudinal and qp.w_lateral == 0.0
    assert (qp.w_speed, qp.k_pv, qp.w_smooth) == (1.0, 20.0, 0.1)  # expert_batch.py rho_v, k_p_v, weight_smoothness
    problem = build_problem(load_scene("static-blockage"), spec.config.basis)
    p = spec.prior(4).propose(problem, jax.random.PRNGKey(0), 50).samples
    goal = goal_from_setpoints(p, problem.init_x, spec.config.basis.horizon)
    model = make_model(spec.config.basis, qp)
    free_end = dataclasses.replace(qp, terminal_position=False, terminal_longitudinal=True)
    assert model.A_x.shape[0] == make_model(spec.config.basis, free_end).A_x.shape[0]  # no x(T) row
    b_x, b_y = boundary_values(problem.init_x, problem.init_y, qp, goal)
    traj = evaluate(model, solve_setpoint_qp(model, p, b_x, b_y))
    np.testing.assert_allclose(np.asarray(traj.y)[:, -1], np.asarray(goal[:, 1]), atol=1e-3)
    np.testing.assert_allclose(np.asarray(traj.vy)[:, -1], 0.0, atol=1e-3)
    # the speed is tracked, not the distance imposed: near the goal's speed by mid-horizon
    mid = np.asarray(traj.vx)[:, 50]
    np.testing.assert_allclose(mid, np.asarray(p[:, 0]), atol=0.5)


def test_the_faithful_batch_plans_one_problem():
    spec = get_optimiser("batch-faithful").with_samples(60).with_overrides(projection={"max_iterations": 5})
    problem = build_problem(load_scene("dense-snapshot"), spec.config.basis)
    result = plan(problem, spec.config, key=jax.random.PRNGKey(0), prior=spec.prior(), method=spec.method)
    assert result.status != PlanStatus.NUMERICAL_ERROR
    for arr in (*result.trajectory, result.coeffs, result.setpoints):
        assert np.all(np.isfinite(arr))


def test_spread_indices_cover_the_table_or_cycle_it():
    np.testing.assert_array_equal(spread_indices(10, 5), [0, 2, 4, 6, 8])
    np.testing.assert_array_equal(spread_indices(3, 7), [0, 1, 2, 0, 1, 2, 0])


def test_the_faithful_vanilla_keeps_the_1000_least_obstructed_of_30000_guesses():
    problem = build_problem(load_scene("dense-snapshot"))
    prior = get_optimiser("vanilla-faithful").prior(4)
    assert isinstance(prior, VanillaGuesses) and (prior.oversampling, prior.num_guess_speeds, prior.speed_spread) == (30, 30, 12.0)
    key = jax.random.PRNGKey(3)
    p = np.asarray(prior.propose(problem, key, 1000).samples)
    assert p.shape == (1000, 8)
    v_des = float(problem.v_des)
    np.testing.assert_array_equal(p[:, :4], p[:, :1].repeat(4, axis=1))  # one speed per guess, no behavioural layer
    assert np.all(p[:, 0] >= v_des - 12 - 1e-4) and np.all(p[:, 0] <= min(v_des + 12, 30.0) + 1e-4)
    assert np.all(p[:, 4:] >= float(problem.y_lb) - 1e-4) and np.all(p[:, 4:] <= float(problem.y_ub) + 1e-4)
    assert len({tuple(row) for row in p.round(3)}) > 900  # 1000 different guesses, not one sample
    # the kept guesses are exactly the least intruding of the 30 x 100 candidates
    v, x, y = prior.candidates(problem, key, 30 * 100)
    assert len(np.unique(np.asarray(v).round(4))) == 30
    intrusion = np.asarray(prior.intrusion(problem, x, y))
    _, kept = prior.guesses(problem, key, 100)
    kept_rows = {tuple(row) for row in np.asarray(kept).round(4)}
    best = {tuple(row) for row in np.asarray(y)[np.argsort(intrusion)[:100]].round(4)}
    assert kept_rows == best and intrusion.max() > np.sort(intrusion)[99]
    # lateral guesses: the road's centre plus smooth noise pinned at both ends (about 7 m std mid-horizon)
    factor = lateral_noise_factor(100)
    std = np.sqrt((factor**2).sum(axis=1))
    assert std[0] < 0.2 and std[-1] < 0.2 and 6.5 < std[50] < 8.0


def test_faithful_gaussians_are_the_authors_and_their_key_advances():
    problem = build_problem(load_scene("dense-snapshot"))
    random_prior, start = get_optimiser("random-faithful").prior(4), get_optimiser("bilevel-faithful").prior(4)
    assert isinstance(random_prior, FixedGaussian) and isinstance(start, FixedGaussian)
    a = np.asarray(random_prior.propose(problem, jax.random.PRNGKey(0), 4000).samples)
    b = np.asarray(random_prior.propose(problem, jax.random.PRNGKey(1), 4000).samples)
    assert not np.allclose(a, b)  # the authors' MPC-Random drew one key for ever; driveopt's key advances
    np.testing.assert_allclose(a[:, :4].mean(axis=0), float(problem.v_des), atol=0.3)  # N(v_des, 16)
    np.testing.assert_allclose(a[:, :4].std(axis=0), 4.0, atol=0.3)
    np.testing.assert_allclose(a[:, 4:].mean(axis=0), float(problem.init_y[0]), atol=0.5)  # N(y0, 46)
    np.testing.assert_allclose(a[:, 4:].std(axis=0), np.sqrt(46.0), atol=0.4)
    assert start.speed_mean == 5.0 and start.speed_var == (30.0,) * 4 and start.lateral_var == (30.0, 46.0, 46.0, 46.0)
    # MPC-Bi-Level draws around the mean its previous call ended with; MPC-Random ignores it
    carried = jnp.asarray([12.0] * 4 + [8.0] * 4)
    c = np.asarray(start.propose(problem, jax.random.PRNGKey(0), 4000, carried).samples)
    np.testing.assert_allclose(c.mean(axis=0), carried, atol=0.4)
    np.testing.assert_array_equal(np.asarray(random_prior.propose(problem, jax.random.PRNGKey(0), 4000, carried).samples), a)
    cvae = get_optimiser("cvae-faithful")
    assert cvae.config == get_optimiser("bilevel-faithful").config
    learned = cvae.prior(4)  # the CVAE's samples, the carried mean and the start's fixed covariance for the first update
    assert isinstance(learned, LearnedStart) and learned.start == start
    proposal = learned.propose(problem, jax.random.PRNGKey(0), 50, carried)
    np.testing.assert_array_equal(np.asarray(proposal.samples),
                                  np.asarray(learned.learned.propose(problem, jax.random.PRNGKey(0), 50, carried).samples))
    np.testing.assert_array_equal(np.asarray(proposal.mean), np.asarray(carried))
    np.testing.assert_array_equal(np.asarray(proposal.cov), np.diag([30.0] * 5 + [46.0] * 3))


def test_p1_authors_ranking_is_their_cost_plus_the_residual():
    """P1's authors' driving cost, against a direct computation of their compute_cost on one trajectory; a heading
    within 10 degrees of the road costs nothing, beyond it as much as the residual."""
    model = make_model()
    problem = build_problem(load_scene("dense-snapshot"))
    b_x, b_y = boundary_values(problem.init_x, problem.init_y, QPConfig())
    setpoints = jnp.asarray([[6.0, 8.0, 10.0, 10.0, 12.0, 12.0, 12.0, 12.0], [10.0] * 4 + [4.0] * 4])
    traj = evaluate(model, solve_setpoint_qp(model, setpoints, b_x, b_y))
    ranking = P1AuthorsRanking(speed_weight=1e-2)
    cost = np.asarray(ranking.driving_cost(traj, problem, None, None))
    vx, vy, ax, ay = (np.asarray(a, np.float64) for a in (traj.vx, traj.vy, traj.ax, traj.ay))
    steering = np.arctan(2.5 * (vx * ay - vy * ax) / np.maximum(np.hypot(vx, vy), 1e-3) ** 3)
    heading = np.arctan2(vy, vx)
    expected = (1e-2 * np.linalg.norm(vx - float(problem.v_des), axis=1)
                + 0.01 * (np.linalg.norm(steering, axis=1) + np.linalg.norm(np.diff(steering, axis=1), axis=1))
                + np.linalg.norm(np.maximum(np.abs(heading) - np.radians(10.0), 0.0), axis=1))
    np.testing.assert_allclose(cost, expected, rtol=1e-4, atol=1e-5)
    lane_change, straight = np.abs(heading).max(axis=1)
    assert lane_change > np.radians(10.0) and straight < 1e-3 and float(ranking.score(cost, 0.0)[0]) > 0.1
    assert float(ranking.score(jnp.asarray(cost), jnp.asarray(0.5))[1]) == pytest.approx(cost[1] + 0.5, rel=1e-6)


def test_p2_authors_ranking_is_their_gated_cost_plus_the_residual():
    """P2's authors' cost (DOptimizerJax.py compute_cost) against a direct computation on two trajectories; the gate
    exp(-2 r) lets an all-infeasible pair be picked by residual, where the ungated cost picks the one that gets further."""
    model = make_model()
    problem = build_problem(load_scene("dense-snapshot"))
    b_x, b_y = boundary_values(problem.init_x, problem.init_y, QPConfig())
    setpoints = jnp.asarray([[20.0] * 4 + [0.0] * 4, [5.0] * 4 + [4.0] * 4])
    traj = evaluate(model, solve_setpoint_qp(model, setpoints, b_x, b_y))
    ranking = P2AuthorsRanking()
    cost = np.asarray(ranking.driving_cost(traj, problem, None, None))
    x, vx, vy, ax, ay = (np.asarray(a, np.float64) for a in (traj.x, traj.vx, traj.vy, traj.ax, traj.ay))
    steering = np.arctan(2.875 * (vx * ay - vy * ax) / np.maximum(np.hypot(vx, vy), 1e-3) ** 3)
    heading = np.arctan2(vy, vx)
    horizon = np.asarray(traj.t, np.float64)[..., -1:]
    expected = (1e-3 * np.linalg.norm(x - float(problem.v_des) * horizon, axis=1)
                + 0.01 * (np.linalg.norm(steering, axis=1) + np.linalg.norm(np.diff(steering, axis=1), axis=1)
                          + np.linalg.norm(np.maximum(np.abs(heading) - np.radians(10.0), 0.0), axis=1)))
    np.testing.assert_allclose(cost, expected, rtol=1e-4, atol=1e-5)
    assert cost[0] < cost[1]  # the faster plan gets further
    residual = jnp.asarray([2.0, 1.9])
    assert np.argmin(np.asarray(ranking.score(jnp.asarray(cost), residual))) == 1
    ungated = P2AuthorsRanking(gate=0.0, progress_weight=1.0)
    assert np.argmin(np.asarray(ungated.score(jnp.asarray(cost) * 1e3, residual))) == 0
    assert float(ranking.score(jnp.asarray(cost), jnp.asarray(0.0))[0]) == pytest.approx(cost[0], rel=1e-6)


@pytest.mark.parametrize("name", P2_FAITHFUL)
def test_p2_faithful_pipelines_keep_samples_prior_and_filter_and_take_p2s_ranking(name):
    strong, spec = get_optimiser(name), get_optimiser(f"{name}-faithful")
    assert spec.config == strong.config.replace(**faithful.P2_MATHS) and spec.config.qp.initial_lateral_acceleration
    assert spec.config.sampler.num_constraint_elites == 150
    # P2's filter: 100 plain iterations at the nodes, whatever driveopt's pipeline runs
    faithful_pass = spec.config.projection
    assert (faithful_pass.max_iterations, faithful_pass.anderson_window, faithful_pass.derivative_bounds) == (100, 0, "nodes")
    own_pass = VQVAE_FILTER_PROJECTION if name == "vqvae-filter" else P2_PASS_PROJECTION  # vqvae-filter's is faster
    assert {field: getattr(strong.config.projection, field) for field in P2_PASS_PROJECTION} == own_pass
    assert spec.make_prior is strong.make_prior and spec.learned_filter == strong.learned_filter
    assert spec.method.ranking == P2AuthorsRanking() and strong.method.ranking == FeasibilityFirst()
    assert spec.loop.command is P2_AUTHORS_COMMAND and not spec.loop.measured_start


@pytest.mark.parametrize("name", ["grid-faithful", "vanilla-faithful", "bilevel-faithful"])
def test_faithful_planners_plan_finite_trajectories(name):
    spec = get_optimiser(name).with_samples(60).with_overrides(projection={"max_iterations": 5})
    problem = build_problem(load_scene("dense-snapshot"), spec.config.basis)
    result = plan(problem, spec.config, key=jax.random.PRNGKey(0), prior=spec.prior(), method=spec.method)
    for arr in (*result.trajectory, result.coeffs, result.setpoints):
        assert np.all(np.isfinite(arr))
