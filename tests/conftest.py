import atexit
import gc
import os
import shutil
import sys
import tempfile

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
# The run starts dozens of Python processes (the xdist workers, the commands tests run in subprocesses): let them cache
# the bytecode of what they import, also where the environment sets PYTHONDONTWRITEBYTECODE, so that each module is
# compiled to bytecode once rather than in every process (the README's test command installs with --no-compile, so
# that only the modules the tests import are compiled).
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
sys.dont_write_bytecode = False
# XLA's CPU backend without LLVM's optimisation passes: the suite spends most of its time compiling (hundreds of small
# configurations, each run a few times), and at level 0 compiling takes about half as long while each call runs the
# same HLO. Measured on the 2-core machine, four of the longest files: 334 s -> 251 s in one process. Results agree to
# float32 rounding (the recorded residuals pass either way); the one comparison that is bit for bit only at LLVM's
# default level says so (test_behaviours' runtime fields). A level set in XLA_FLAGS is kept.
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_backend_optimization_level=0".strip()
# JAX's persistent compilation cache in a folder of this test run's own: empty when the run starts (nothing carried
# over from earlier runs or from the user's cache, which is never read or written), shared by the xdist workers and
# the commands that tests start in subprocesses (they inherit the environment), so that a configuration compiled by
# one process loads in the others; removed when the run ends. Tests of the cache set their own folders.
if "DRIVEOPT_COMPILATION_CACHE" not in os.environ:
    _cache = tempfile.mkdtemp(prefix="driveopt-tests-jax-")
    os.environ["DRIVEOPT_COMPILATION_CACHE"] = _cache
    atexit.register(shutil.rmtree, _cache, ignore_errors=True)

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from driveopt.config import PlannerConfig
from driveopt.sim.traffic import restore_traffic_constants, traffic_constants

_UPSTREAM_TRAFFIC = traffic_constants()  # before any test makes an env


@pytest.fixture(autouse=True)
def _upstream_traffic():
    """Each test starts from upstream's traffic constants, whatever env an earlier test in its process reset
    (intersection-v0 changes them for the process: driveopt.sim.traffic)."""
    restore_traffic_constants(_UPSTREAM_TRAFFIC)
    yield

# One small configuration shared by the tests, so that it compiles once per session.
SMALL = PlannerConfig().replace(
    sampler=dict(num_samples=250, num_iterations=4, num_constraint_elites=80, num_elites=30),
    projection=dict(max_iterations=20),
)


# Every runtime field of the configuration (driveopt.config.RUNTIME_FIELDS) at another value than its default.
RUNTIME_CHANGES = {"projection": {"v_min": 0.5, "a_max": 4.5},
                   "cost": {"speed": 2.0, "lateral_acceleration": 0.1, "heading": 10.0, "curvature": 5.0, "lane_centering": 1.0,
                            "consistency": 1.0, "route": 5.0, "lane_flow": 4.0}}

# End-to-end tests that run only with ``-m slow`` (benchmark-sized: each compiles a planner configuration of its own
# or trains through one): what each checks is also checked in the default suite by a faster test, named here.
SLOW = {
    # every registered planner still drives in test_every_planner_runs_... for bilevel, cvae, vqvae-filter, grid-p1, idm,
    # dqn, ppo (one of each kind: Gaussian, learned prior, learned filter, P1-faithful baseline, rule-based, RL)
    **{f"tests/experiments/test_rollout.py::test_every_planner_runs_on_every_road_layout_and_lane_count[{name}]": "rollout"
       for name in ("bilevel-p1", "cvae-mix", "vqvae", "vqvae-cem", "cvae-filter", "cvae-multipliers", "random", "grid",
                    "vanilla", "batch", "random-p1", "vanilla-p1", "batch-p1")},
    "tests/experiments/test_rollout.py::test_a_closed_loop_compiles_its_planner_once[vqvae]": "the [bilevel] case",
    "tests/experiments/test_rollout.py::test_the_loop_carries_the_executed_plan_when_consistency_is_weighed[grid]":
        "the [bilevel] case",
    # the baselines' finite plans: test_baselines_plan_finite_trajectories[grid] and the closed loop of grid-p1
    **{f"tests/core/test_registry.py::test_baselines_plan_finite_trajectories[{name}]": "the [grid] case"
       for name in ("random", "vanilla", "batch")},
    # gradients: test_solve's test_grad_through_solve_... and test_cvae's finite-difference check of the QP layer
    "tests/training/test_filter.py::test_grad_of_the_eq9_loss_is_finite_and_matches_finite_differences": "gradients",
    "tests/core/test_projection.py::test_unrolled_projection_is_differentiable": "gradients",
    "tests/learned/test_cvae_multipliers_network.py::test_gradients_of_the_loss_are_finite_and_reach_every_part":
        "gradients: tests/training/test_cvae_multipliers.py's falling loss",
    # per-sample and zero-iteration filters: test_gamma_one_and_zero_initialisation_reproduce_the_plain_projection_exactly
    "tests/training/test_filter.py::test_per_sample_gammas_project_each_sample_as_alone": "gamma one and zero",
    "tests/training/test_filter.py::test_zero_projection_iterations_return_the_sampled_trajectories_unchanged":
        "gamma one and zero",
    # open: the placeholder row changes rounding in a batch one row longer (xfail)
    "tests/core/test_solve.py::test_absent_warm_start_and_previous_plan_give_the_result_of_a_call_without_them": "xfail",
    "tests/core/test_solve.py::test_status_is_decided_inside_the_compiled_call_and_matches_plan": "test_planner's statuses",
    # the straightening fallback: tests/cli/test_reliability.py's test_a_straightening_fallback_is_a_stop_too
    "tests/core/test_behaviours.py::test_fallback_straightens_is_a_planner_setting": "reliability property",
    # PixelCNN's incremental sampler: the [tiny] case
    **{f"tests/learned/test_pixelcnn_sampling.py::test_incremental_sampling_draws_what_the_full_network_draws[{name}]":
       "the [tiny] case" for name in ("short-kernel", "default")},
    # benchmark scripts: their records are committed; the library paths they call are tested in the default suite
    **{f"tests/benchmarks/test_{name}.py": "benchmark script" for name in (
        "filter_timing", "filter_residuals", "call_profile", "latency_bench", "compile_cost", "projection_split",
        "matmul_peak", "suite_compiles")},
    # the commands that replay and compare closed-loop episodes: their option checks run in the default suite
    "tests/experiments/test_trace_episode.py::test_the_trace_replays_the_bench_episode_step_by_step": "episode replay",
    "tests/experiments/test_closed_loop_ab.py::test_a_tree_against_itself_is_identical_and_a_rerun_resumes":
        "episode replay",
    "tests/benchmarks/test_faithful_ablation.py::test_episodes_are_written_and_a_rerun_resumes": "benchmark script",
    "tests/experiments/test_prior_metrics.py::test_the_script_writes_json_resumes_and_refuses_other_settings":
        "benchmark script",
    # gradients through solve and the projection: test_cvae's finite-difference check of the QP layer
    "tests/core/test_solve.py::test_grad_through_solve_with_respect_to_the_initial_coefficients_is_finite": "gradients",
    # row kinds and carried inputs: test_the_placeholder_row_is_in_solve_s_batch_but_never_ranked, test_rollout's
    # test_a_closed_loop_compiles_its_planner_once[bilevel] (warm start and previous plan carried)
    "tests/core/test_solve.py::test_appended_rows_carry_their_kind": "placeholder row",
    "tests/core/test_solve.py::test_a_warm_start_and_a_previous_plan_reach_the_result_whichever_way_they_are_passed":
        "closed loop carries both",
    # sideways emergency stops: the reliability property's stops and test_the_fallback_is_the_stop_that_reaches_...
    "tests/core/test_behaviours.py::test_the_far_lane_stop_leaves_the_lane_of_the_car_it_would_meet": "fallback choice",
    "tests/experiments/test_rollout.py::test_every_planner_runs_on_every_road_layout_and_lane_count[cvae]":
        "the [vqvae-filter] case (a learned prior)",
    # consistency: test_behaviours' test_the_previous_plan_keeps_winning_between_equal_manoeuvres
    "tests/experiments/test_rollout.py::test_the_loop_carries_the_executed_plan_when_consistency_is_weighed[bilevel]":
        "consistency",
    # the cache's switch, kept folder and concurrent writers: the other tests of test_compilation_cache.py;
    # its start-up time: benchmarks/perf/startup.py
    "tests/cli/test_compilation_cache.py::test_a_second_plan_loads_the_planner_from_the_cache": "startup benchmark",
    # resuming collect: test_collect_resumes_without_duplicates; stopping on signals: tests/cli/test_interrupts.py
    "tests/data/test_demonstrations.py::test_terminated_collect_keeps_finished_episodes_and_resumes": "resume, signals",
    "tests/training/test_cvae.py::test_file_order_changes_neither_split_nor_training": "test_harness's split",
    "tests/cli/test_reliability.py::test_plan_with_no_repeats_says_it_timed_nothing": "CLI message",
    # shipped weights plan feasibly: the two-lane case of each
    "tests/training/test_filter.py::test_shipped_filter_weights_load_by_default_and_plan_feasibly[4-slow-leader-four-lane]":
        "the two-lane case",
    "tests/training/test_vqvae.py::test_shipped_vqvae_weights_load_by_default_and_plan_feasibly[4-slow-leader-four-lane]":
        "the two-lane case",
    # `plan --filter-weights` (the vqvae-filter planner, compiled only here): the option reaches the planner's spec in
    # test_any_optimiser_takes_a_filter_checkpoint_..., a learned filter plans in test_rollout's [vqvae-filter] case
    "tests/training/test_filter.py::test_plan_command_plans_with_a_filter_checkpoint": "filter weights option",
    # learned priors planning: test_cvae_filter's static blockage (the CVAE prior), test_rollout's [vqvae-filter]
    "tests/training/test_cvae.py::test_cvae_prior_in_the_planner": "test_cvae_filter",
    "tests/training/test_vqvae.py::test_vqvae_planners_without_weights_warn_and_plan": "test_cvae's warnings",
    # training data and resumes: tests/training/test_harness.py (split, resume), tests/data/test_demonstrations.py
    "tests/training/test_cvae.py::test_training_resumes_to_the_same_weights": "test_harness",
    "tests/training/test_cvae.py::test_train_episodes_shrinks_training_set_and_keeps_validation": "test_harness",
    "tests/training/test_vqvae.py::test_collect_writes_schema_2_modes": "test_demonstrations",
    "tests/training/test_filter.py::test_gamma_one_and_zero_initialisation_reproduce_the_plain_projection_exactly":
        "test_filter's other tests of the trained filter",
    # the fallback's choice: test_the_fallback_is_the_stop_that_reaches_an_obstacle_later
    "tests/core/test_behaviours.py::test_evasion_offers_a_stop_past_a_car_that_every_stop_in_the_lane_would_touch":
        "fallback choice",
    "tests/core/test_behaviours.py::test_a_stop_is_feasible_curvature_is_not_applied_at_standstill":
        "test_a_feasible_stop_beats_infeasible_samples",
    # P1's ranking: test_behaviours' test_p1_baselines_rank_by_residual_first_as_the_authors_code
    "tests/core/test_solve.py::test_p1_ranking_picks_the_lowest_cost_plus_residual_even_when_infeasible": "P1 ranking",
    # accepted keys and offsets: the refusals in test_planner and every other test's PRNGKey
    "tests/core/test_planner.py::test_typed_keys_numpy_keys_and_real_offsets_plan": "key checks",
    "tests/core/test_projection.py::test_unrolled_equals_early_stopping_loop[0.35-0.001-0.01]": "the other case",
    # closed loops: every scenario builds and steps (tests/sim/test_sim_env.py); bench options (test_experiments);
    # a curved road driven by the controller: tests/viz/test_plan_overlay.py (racetrack-v0) and the slow six-env test
    "tests/experiments/test_rollout.py::test_every_scenario_runs": "test_sim_env",
    "tests/experiments/test_rollout.py::test_bench_config_overrides_reach_every_optimiser_and_fix_the_folder":
        "test_experiments' bench options",
    "tests/experiments/test_experiments.py::test_scenario_overrides_and_replan_period_are_bench_options":
        "bench options",
    "tests/core/test_controller.py::test_racetrack_is_driven_for_20_s_without_leaving_the_track": "overlay test",
    "tests/experiments/test_prior_metrics.py::test_row_metrics_of_a_hand_made_prior_on_an_empty_road": "prior metrics",
    "tests/benchmarks/test_stop_property.py": "benchmark script",
    "tests/training/test_vqvae.py::test_demonstrations_table_counts_modes_and_lanes_and_refuses_bad_files":
        "benchmark script",
    # the fallback's choice: test_the_fallback_is_the_stop_that_reaches_an_obstacle_later; its stops' promises with
    # evasion on (the default): tests/cli/test_reliability.py's property
    "tests/core/test_behaviours.py::test_evasion_leaves_the_fallback_alone_where_no_stop_in_the_lane_touches_a_car":
        "fallback choice",
    # the optimiser driver plans from the car's state at every step of test_rollout's closed loops, whose plans the
    # tracker follows (tests/sim/test_sim_control.py's open-loop tracking of a lane and speed change)
    "tests/drivers/test_drivers.py::test_optimiser_driver_plans_from_the_current_state_and_returns_a_valid_action":
        "closed loops",
    "tests/sim/test_sim_control.py::test_open_loop_tracking_of_a_planner_result": "closed loops",
    "tests/core/test_registry.py::test_faithful_planners_plan_finite_trajectories[vanilla-faithful]":
        "test_rollout's [vanilla-faithful] case",
}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.nodeid in SLOW or item.nodeid.split("::")[0] in SLOW:
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session")
def small_config() -> PlannerConfig:
    return SMALL


@pytest.fixture(autouse=True, scope="session")
def plan_without_exports():
    """The tests' planning calls run ``solve`` as a plain jit, not through exported graphs: in a suite where almost every
    graph is new, exporting costs about 0.8 s per graph and saves nothing (results are bit-identical either way:
    tests/core/test_solve_export.py, which points the export at a folder of its own)."""
    from driveopt import solve_export

    folder = solve_export.export_folder
    solve_export.export_folder = lambda: None
    yield
    solve_export.export_folder = folder


class _RecordedGraphs(dict):
    """``exported_solve().calls`` that records the graph every call looks up."""

    def __init__(self, graphs, used: list):
        super().__init__(graphs)
        self.used = used

    def get(self, graph, default=None):
        self.used.append(graph)
        return super().get(graph, default)


@pytest.fixture
def solve_graphs(monkeypatch) -> list:
    """The graphs (``exported_solve().calls``' keys: static arguments, argument structure and shapes) that the test's
    planning calls run, one entry per call: one distinct entry means one compilation."""
    from driveopt.planner import exported_solve

    used: list = []
    monkeypatch.setattr(exported_solve(), "calls", _RecordedGraphs(exported_solve().calls, used))
    return used


def mapped_regions() -> int:
    """Memory mappings of this process (Linux; 0 where /proc is missing)."""
    try:
        with open("/proc/self/maps") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return 0


def map_limit() -> int:
    try:
        with open("/proc/sys/vm/max_map_count") as limit:
            return int(limit.read())
    except (OSError, ValueError):
        return 65530  # Linux's default


@pytest.fixture(autouse=True)
def release_compiled_code_before_the_map_limit():
    """jaxlib >= 0.10 JITs every fused kernel of a CPU executable into its own three memory mappings (~1200 for one
    planner), and JAX keeps every executable it compiled. An xdist worker reached ~60000 mappings by the end of the
    suite; at Linux's limit (vm.max_map_count, 65530 by default) the next compile's mmap fails and the worker
    segfaults, which hangs the run. Past half the limit, the compiled code is dropped (later tests recompile)."""
    yield
    if mapped_regions() > map_limit() // 2:
        jax.clear_caches()
        gc.collect()


def reset_env(scenario, seed: int, **make_kwargs):
    """A driveopt env (:func:`driveopt.sim.env.make_env`) of ``scenario`` (a Scenario or a registered name), reset
    with ``seed``."""
    from driveopt.sim.env import make_env
    from driveopt.sim.scenarios import get_scenario

    env = make_env(get_scenario(scenario) if isinstance(scenario, str) else scenario, **make_kwargs)
    env.reset(seed=seed)
    return env


def box_corners(x: float, y: float, heading: float, length: float, width: float) -> np.ndarray:
    """(4, 2) corners of an oriented rectangle centred at (x, y)."""
    c, s = np.cos(heading), np.sin(heading)
    half = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [length / 2, width / 2]
    return np.array([x, y]) + half @ np.array([[c, s], [-s, c]])


def boxes_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test for two convex quadrilaterals given by their corners."""
    for poly in (a, b):
        for i in range(4):
            edge = poly[(i + 1) % 4] - poly[i]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = a @ axis, b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


def lane_change(model, problem, speed: float, y_end: float, duration: float):
    """The plan (a Trajectory of ``model``) from ``problem``'s start at ``speed`` [m/s] along the road, easing from the
    ego's lateral position to ``y_end`` [m] over ``duration`` [s] (a smoothstep), then holding it."""
    from driveopt.config import QPConfig
    from driveopt.qp import boundary_values, fit_positions
    from driveopt.trajectory import evaluate

    t = np.asarray(model.t)
    u = np.clip(t / duration, 0.0, 1.0)
    y0 = float(problem.init_y[0])
    y = y0 + (y_end - y0) * u * u * (3.0 - 2.0 * u)
    b_x, b_y = boundary_values(problem.init_x, problem.init_y, QPConfig())
    return evaluate(model, fit_positions(model, np.float32(speed * t)[None], np.float32(y)[None], b_x, b_y)[0])
