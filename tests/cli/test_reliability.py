"""Reliability promises (docs/results/reliability.md): the fallback is a stop that never changes the sign of the velocity, no
NaN for any accepted input, inputs beyond the physical ranges and mistyped JSON are refused with one clear line."""

import json
import math

import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from driveopt.checks import ConfigError
from driveopt.cli import main
from driveopt.config import from_dict
from driveopt.experiments.rollout import Rollout
from driveopt.fallback import Fallback
from driveopt.method import Method
from driveopt.planner import PlanStatus, plan
from driveopt.problem import build_problem
from driveopt.scene import EgoState, Neighbour, ProblemError, Road, Scene, load_scene, scene_from_dict

from conftest import SMALL

TOLERANCE = 1e-3  # [m/s], [m] float32 slack of the checks below
STOP_COURSE = 0.5  # [-] |vy| / speed up to which a stop starts on the ego's course (driveopt.fallback._course)
# The properties below hold for any batch: the drawn problems are planned with a quarter of SMALL's samples, which makes
# each of their 75 planning calls about three times cheaper (one compilation more).
FUZZ = SMALL.replace(sampler=dict(num_samples=64, num_constraint_elites=24, num_elites=12))


def assert_finite(result):
    for arr in (*result.trajectory, *result.fallback, result.coeffs, result.setpoints, result.mean):
        assert np.all(np.isfinite(arr))
    assert all(math.isfinite(v) for v in (*result.residuals.values(), *result.costs.values(), result.fallback_residual))


def assert_fallback_is_a_stop(result, scene):
    """Speed never rises and never goes below zero, and the velocity never changes sign: the stop starts with the ego's
    speed in its direction of travel (with its velocity, where its course is within the stop's), ends at rest where
    the horizon allows, and never moves against the direction of travel (a reversing ego brakes its backward motion
    and never moves forwards); the car never turns back, the lateral motion stays on the road (or, off it, never moves
    further away), and it starts where the ego is. An ego whose vx is within TOLERANCE of 0 has no direction to keep:
    its stop may go either way, but one way only."""
    fb, ego = result.fallback, scene.ego
    if abs(ego.vx) > TOLERANCE:
        direction = math.copysign(1.0, ego.vx)
    else:
        direction = -1.0 if fb.x[-1] < fb.x[0] else 1.0
    assert np.all(np.diff(fb.speed) <= TOLERANCE) and np.all(fb.speed >= -TOLERANCE)
    assert fb.speed[0] == pytest.approx(ego.speed, abs=TOLERANCE)
    if abs(ego.vy) <= STOP_COURSE * ego.speed:
        assert (fb.vx[0], fb.vy[0]) == pytest.approx((ego.vx, ego.vy), abs=TOLERANCE)
    assert np.all(direction * fb.vx >= -TOLERANCE)  # never against the direction of travel, forwards or backwards
    assert np.all(direction * np.diff(fb.x) >= -TOLERANCE)
    if ego.speed <= result.fallback_deceleration * fb.t[-1]:
        assert fb.speed[-1] <= TOLERANCE and abs(fb.vx[-1]) <= TOLERANCE
    assert fb.x[0] == pytest.approx(ego.x, abs=TOLERANCE) and fb.y[0] == pytest.approx(ego.y, abs=TOLERANCE)
    low, high = scene.lateral_bounds
    if low <= ego.y <= high:
        assert np.all((fb.y >= low - TOLERANCE) & (fb.y <= high + TOLERANCE))
    else:
        distance = np.maximum(low - fb.y, 0.0) + np.maximum(fb.y - high, 0.0)
        assert np.all(np.diff(distance) <= TOLERANCE)


def assert_success_keeps_its_direction(result, scene, config):
    """A SUCCESS plan never moves against the ego's direction of travel (backwards for an ego with vx < 0) beyond the
    feasibility tolerance: its velocity residual, an L2 norm over the nodes, is within ``residual_tolerance``."""
    if result.status != PlanStatus.SUCCESS:
        return
    direction = -1.0 if np.float32(scene.ego.vx) < 0.0 else 1.0
    assert np.all(direction * np.asarray(result.trajectory.vx) >= -config.sampler.residual_tolerance - TOLERANCE)


neighbour = st.builds(
    Neighbour,
    x=st.floats(-60, 150), y=st.floats(-6.0, 22.0), vx=st.floats(-2.0, 35.0), vy=st.floats(-2.0, 2.0),
    length=st.floats(2.0, 14.0), width=st.floats(1.2, 3.0), accel=st.floats(-8.0, 3.0),
    yaw=st.one_of(st.none(), st.floats(-0.5, 0.5)),
)


@settings(max_examples=50, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(
    lanes=st.integers(1, 5), lane_width=st.floats(3.0, 5.0), curvature=st.floats(-0.02, 0.02),
    ego_y=st.floats(-15.0, 30.0), ego_v=st.floats(-40.0, 40.0), ego_vy=st.floats(-3.0, 3.0),
    ego_ax=st.floats(-6.0, 6.0), ego_ay=st.floats(-3.0, 3.0),
    neighbours=st.lists(neighbour, max_size=16), v_des=st.floats(0.0, 40.0),
)
def test_any_accepted_problem_gives_finite_results_and_a_stopping_fallback(
    lanes, lane_width, curvature, ego_y, ego_v, ego_vy, ego_ax, ego_ay, neighbours, v_des
):
    scene = Scene(
        ego=EgoState(x=0.0, y=ego_y, vx=ego_v, vy=ego_vy, ax=ego_ax, ay=ego_ay),
        road=Road(num_lanes=lanes, lane_width=lane_width, curvature=curvature),
        neighbours=tuple(neighbours), v_des=v_des,
    )
    result = plan(build_problem(scene, FUZZ.basis), FUZZ, key=jax.random.PRNGKey(0))
    assert result.status in tuple(PlanStatus)
    assert_finite(result)
    assert_fallback_is_a_stop(result, scene)
    assert_success_keeps_its_direction(result, scene, FUZZ)


@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(  # reversing egos' stops: the property above and test_behaviours' mirrored stops
    ego_y=st.floats(-15.0, 30.0), ego_v=st.floats(-2.0, 40.0), ego_vy=st.floats(-3.0, 3.0),
    neighbours=st.lists(neighbour, max_size=8),
)
def test_a_straightening_fallback_is_a_stop_too(ego_y, ego_v, ego_vy, neighbours):
    """``Fallback.straightens``: the same promises, and the path points along the road once the car stands."""
    scene = Scene(ego=EgoState(x=0.0, y=ego_y, vx=ego_v, vy=ego_vy), road=Road(num_lanes=3), neighbours=tuple(neighbours))
    result = plan(build_problem(scene, FUZZ.basis), FUZZ, key=jax.random.PRNGKey(0),
                  method=Method(fallback=Fallback(straightens=True)))
    assert_finite(result)
    assert_fallback_is_a_stop(result, scene)
    fb = result.fallback
    standing = np.asarray(fb.speed) <= 1e-6
    # a path still turning at the stop: only where the curvature bound cannot straighten a steep course in time
    assert np.all(np.abs(np.asarray(fb.heading)[standing]) <= np.abs(fb.heading[0]) + TOLERANCE)


def test_a_straightening_stop_shorter_than_its_easing_ends_along_the_road():
    """Found by the property above over egos at -40 to 40 m/s: 1 m/s, 1 m beside a lane centre, stops in 0.17 m."""
    scene = Scene(ego=EgoState(x=0.0, y=1.0, vx=1.0), road=Road(num_lanes=3))
    fb = plan(build_problem(scene, FUZZ.basis), FUZZ, key=jax.random.PRNGKey(0),
              method=Method(fallback=Fallback(straightens=True))).fallback
    assert np.all(np.abs(np.asarray(fb.heading)[np.asarray(fb.speed) <= 1e-6]) <= TOLERANCE)


def test_the_fallback_stops_where_the_projected_stop_reversed(small_config):
    """static-blockage with 1000 random neighbours: the fallback drove 21 m backwards before."""
    rng = np.random.default_rng(0)
    base = load_scene("static-blockage")
    crowd = tuple(Neighbour(x=float(x), y=float(y), vx=float(v)) for x, y, v in
                  zip(rng.uniform(-50, 150, 1000), rng.uniform(-2, 14, 1000), rng.uniform(0, 20, 1000)))
    scene = Scene(ego=base.ego, road=base.road, neighbours=base.neighbours + crowd)
    result = plan(build_problem(scene, small_config.basis), small_config, key=jax.random.PRNGKey(0))
    assert result.status == PlanStatus.INFEASIBLE
    assert_fallback_is_a_stop(result, scene)
    assert result.safe_trajectory is result.fallback


def test_an_off_road_ego_gets_a_stop_that_does_not_speed_up(small_config):
    """ego at y = 100 (off the road): the fallback accelerated from 15 to 36 m/s before."""
    scene = Scene(ego=EgoState(x=0.0, y=100.0, vx=15.0), road=Road(num_lanes=4))
    result = plan(build_problem(scene, small_config.basis), small_config, key=jax.random.PRNGKey(0))
    assert result.fallback.speed.max() <= 15.0 + TOLERANCE
    assert_fallback_is_a_stop(result, scene)


@pytest.mark.parametrize("vx, vy", [(-15.0, 0.0), (-95.0, 2.0), (-0.5, 1.5)])
def test_a_reversing_ego_gets_a_stop_that_brakes_its_backward_motion(small_config, vx, vy):
    """A reversing ego's fallback started forwards at its speed: from vx -15 m/s at +15 m/s, from -95 m/s at up to
    118 m/s for 519 m forwards. It brakes the backward motion to rest now, and never moves forwards."""
    scene = Scene(ego=EgoState(x=50.0, y=4.0, vx=vx, vy=vy), road=Road(num_lanes=3))
    result = plan(build_problem(scene, small_config.basis), small_config, key=jax.random.PRNGKey(0), x_offset=scene.ego.x)
    fb = result.fallback
    assert fb.vx[0] < 0.0 and fb.x[-1] < scene.ego.x and fb.speed.max() <= scene.ego.speed + TOLERANCE
    assert_fallback_is_a_stop(result, scene)


def test_the_fallback_brakes_to_a_stop_in_closed_loop():
    """A speed floor no plan can meet (the car starts below it, so every plan's first node breaks it): every step
    that executes the fallback slows the car down, never below zero, never backwards. (A floor rather than a ceiling:
    ``projection.v_min`` is an input of the compiled planner, so this loop runs the registered grid's compilation.)"""
    rollout = Rollout("two-lane-d1.0", _unreachable_speed_bound().driver(), seed=3, duration=3.0)
    fallback_steps = []
    for step in rollout:
        if step.decision.result.status != PlanStatus.SUCCESS:
            fallback_steps.append(len(step.episode.speeds))  # index of the speed after this step
    speeds = np.asarray(rollout.episode.speeds)
    assert len(fallback_steps) >= 10 and not rollout.episode.collided and np.all(speeds >= 0.0)
    before = np.concatenate([[speeds[0] + 1.0], speeds])  # speed before each step (the first: unknown, any)
    assert all(speeds[i] <= before[i] + 1e-6 for i in fallback_steps[1:])
    assert speeds[fallback_steps[-1]] < speeds[0] - 5.0


def _unreachable_speed_bound():
    from driveopt.registry import get_planner

    return get_planner("grid").with_overrides(projection={"v_min": 29.9})


@pytest.mark.parametrize("field, value, needle", [
    ("vx", 1e30, "ego.vx must be within [-100, 100] m/s"),
    ("y", 1e30, "ego.y must be within"),
    ("ax", 1e5, "ego.ax must be within"),
    ("x", True, "ego.x must be a number, got True"),
    ("x", "5", "ego.x must be a number, got '5'"),
])
def test_out_of_range_and_mistyped_ego_values_are_refused(field, value, needle):
    data = {"ego": {"x": 0.0, "y": 4.0, "vx": 10.0, field: value}}
    with pytest.raises(ProblemError) as exc:
        scene_from_dict(data)
    assert needle in str(exc.value)


def test_a_negative_edge_margin_no_longer_widens_the_road():
    with pytest.raises(ProblemError, match=r"edge_margin must be within \[0, 100\] m"):
        scene_from_dict({"ego": {"x": 0, "y": 4, "vx": 10}, "edge_margin": -100})


@pytest.mark.parametrize("data, needle", [
    ({"projection": {"barrier": "false"}}, "projection.barrier must be true or false, got 'false'"),
    ({"qp": {"initial_acceleration": "no"}}, "qp.initial_acceleration must be true or false"),
    ({"projection": {"barrier": [1]}}, "projection.barrier must be true or false, got [1]"),
    ({"projection": {"a_max": "abc"}}, "projection.a_max must be a number, got 'abc'"),
    ({"projection": {"rho_obstacle": float("inf")}}, "projection.rho_obstacle must be finite"),
    ({"basis": {"horizon": 1e30}}, "basis.horizon must be in [1, 120] s"),
    ({"sampler": {"temperature": None}}, "sampler.temperature must be a number, got None"),
    ({"stop_rows": False}, "unknown config section 'stop_rows'"),
    ({"sampler": {"num_samples": 250.0}}, "sampler.num_samples must be an integer"),
])
def test_config_values_are_typed_and_in_range(data, needle):
    with pytest.raises(ConfigError) as exc:
        from_dict(data)
    assert needle in str(exc.value)


def _one_line_error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("driveopt: error:") and "\n" not in err and "Traceback" not in err
    return err


def test_bad_inputs_on_the_command_line_are_one_line_errors(tmp_path, capsys):
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"cost": {"speed": None}}))
    assert "cost.speed" in _one_line_error(capsys, ["plan", "--config", str(cfg)])
    cfg.write_text(json.dumps({"projection": {"rho_obstacle": 1e400}}))  # parses to inf
    assert "finite" in _one_line_error(capsys, ["plan", "--config", str(cfg)])
    cfg.write_text(json.dumps({"sampler": {"num_samples": 250}}))  # and --samples another count: neither is dropped
    for command in ("plan", "drive"):
        assert "disagree" in _one_line_error(capsys, [command, "--samples", "150", "--config", str(cfg)])
    problem = tmp_path / "p.json"
    problem.write_text(json.dumps({"ego": {"x": 0, "y": 1e30, "vx": 15}}))
    assert "ego.y must be within" in _one_line_error(capsys, ["plan", "--problem", str(problem)])
    assert "is a directory" in _one_line_error(capsys, ["plan", "--json", str(tmp_path)])
    blocked = tmp_path / "file"
    blocked.write_text("x")
    assert "cannot be written" in _one_line_error(capsys, ["plan", "--json", str(blocked / "r.json")])


def test_a_huge_seed_is_an_argument_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["plan", "--seed", "100000000000000000000000"])
    assert exc.value.code == 2 and "seed must be in [0, 4294967295]" in capsys.readouterr().err


def test_plan_with_no_repeats_says_it_timed_nothing(capsys):
    assert main(["plan", "--samples", "60", "--iterations", "1", "--projection-iterations", "5", "--repeats", "0"]) == 0
    out = capsys.readouterr().out
    assert "--repeats 0" in out and "median of 0" not in out


def test_the_video_writer_raises_no_fork_warning(tmp_path):
    """The default drive printed JAX's os.fork() warning when the writer started ffmpeg."""
    import warnings

    import jax.numpy as jnp

    from driveopt.viz.video import VideoWriter

    jnp.zeros(3).block_until_ready()  # JAX is running: its fork detector is armed
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with VideoWriter(tmp_path / "v.mp4", fps=10) as writer:
            for _ in range(3):
                writer.append(np.zeros((32, 48, 3), np.uint8))
    assert not [w for w in caught if "fork" in str(w.message)]
    assert (tmp_path / "v.mp4").stat().st_size > 0


def test_drive_says_it_is_compiling(tmp_path, capsys):
    assert main(["drive", "--scenario", "two-lane-d1.0", "--planner", "grid", "--duration", "0.3", "--video", ""]) == 0
    assert "compiling" in capsys.readouterr().err


def test_drive_exits_1_when_every_planning_call_ended_in_a_numerical_error(tmp_path, capsys, monkeypatch):
    """The car followed the fallback throughout: the command says so and fails, after writing its JSON."""
    from driveopt.drivers import optimiser
    from driveopt.planner import PlanStatus

    real_plan = optimiser.plan
    monkeypatch.setattr(optimiser, "plan", lambda *args, **kwargs: real_plan(*args, **kwargs)._replace(
        status=PlanStatus.NUMERICAL_ERROR))
    out = tmp_path / "d.json"
    argv = ["drive", "--scenario", "two-lane-d1.0", "--planner", "grid", "--duration", "0.3", "--video", "", "--json", str(out)]
    assert main(argv) == 1
    assert "every planning call of grid ended in NUMERICAL_ERROR" in capsys.readouterr().err
    assert json.loads(out.read_text())["statuses"] == {"NUMERICAL_ERROR": 3}
