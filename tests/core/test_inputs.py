"""Input files and values are checked before any work starts: problem files, planner-config files and scenario
override files go through one reader; a value that cannot run is a one-line error, never a traceback or a hang."""

from __future__ import annotations

import json
import os

import pytest

from driveopt.checks import ConfigError
from driveopt.cli import main
from driveopt.cli.common import UsageError, config_overrides
from driveopt.scene import ProblemError, Scene, UnknownProblemError, load_scene, scene_from_dict

EGO = {"x": 0, "y": 4, "vx": 10}
FAST = ["--samples", "60", "--iterations", "1", "--projection-iterations", "2", "--repeats", "0"]
BEYOND_THE_READER = [
    ('{"ego": {"x": 0, "y": 4, "vx": ' + "1" * 400 + "}}", "has 400 characters"),
    ('{"ego": ' * 50_000 + "{}" + "}" * 50_000, "nested deeper than"),
    (json.dumps({"name": "\ud800", "ego": EGO}), "not valid Unicode"),
    ('{"ego": {"x": 0, "y": 4, "vx": Infinity}}', "Infinity is not a JSON number"),
]


def _write(tmp_path, text: str, name: str = "input.json"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _one_line_error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("driveopt: error: ") and err.count("\n") == 1, err
    return err


@pytest.mark.parametrize("text, needle", BEYOND_THE_READER)
def test_problem_files_beyond_the_reader_limits_are_refused(tmp_path, capsys, text, needle):
    path = _write(tmp_path, text)
    with pytest.raises(ProblemError, match=needle):
        load_scene(path)
    assert needle in _one_line_error(capsys, ["plan", "--problem", str(path), *FAST])


# Runs CLI commands (one JSON list of arguments each) in a child whose memory is capped once its modules are imported
# and which an alarm ends: were a special file read, /dev/zero would take all the memory and a FIFO without a writer
# would block forever; were a plan that cannot finish started, it would run for hours.
_CLI_CHILD = """
import json, resource, signal, sys
from driveopt.cli import main
with open("/proc/self/status") as status:
    size = next(int(line.split()[1]) for line in status if line.startswith("VmSize:")) * 1024
hard = resource.getrlimit(resource.RLIMIT_AS)[1]
resource.setrlimit(resource.RLIMIT_AS, (size + 2**31 if hard == resource.RLIM_INFINITY else min(size + 2**31, hard), hard))
signal.alarm(60)
for argv in sys.argv[1:]:
    print("status", main(json.loads(argv)), flush=True)
"""


def _cli_in_child(*commands: list[str]) -> tuple[list[int], list[str]]:
    """(exit statuses, stderr lines) of ``commands`` run by the CLI in a capped child process."""
    import subprocess
    import sys

    child = subprocess.run([sys.executable, "-c", _CLI_CHILD, *map(json.dumps, commands)], capture_output=True,
                           text=True, timeout=300, check=False, env={**os.environ, "DRIVEOPT_ALLOW_LARGE": ""})
    statuses = [int(word) for word in child.stdout.split() if word != "status"]
    assert len(statuses) == len(commands), child.stderr[-2000:]
    return statuses, child.stderr.splitlines()


@pytest.mark.skipif(not hasattr(os, "mkfifo") or not os.path.exists("/dev/zero"), reason="POSIX special files")
def test_special_files_as_problem_files_are_refused_at_once(tmp_path):
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    statuses, errors = _cli_in_child(["plan", "--problem", "/dev/zero", "--repeats", "0"],
                                     ["plan", "--problem", str(fifo), "--repeats", "0"])
    assert statuses == [2, 2]
    assert errors == ["driveopt: error: problem file /dev/zero: not a regular file (a character device)",
                      f"driveopt: error: problem file {fifo}: not a regular file (a FIFO)"]


def test_a_plan_that_cannot_finish_is_refused_before_compiling():
    statuses, errors = _cli_in_child(["plan", "--samples", "100000", "--iterations", "1000",
                                      "--projection-iterations", "10000", "--repeats", "0"])
    assert statuses == [2] and len(errors) == 1
    assert "planning work per call" in errors[0] and "DRIVEOPT_ALLOW_LARGE=1" in errors[0]


def test_obstacles_beyond_the_compile_limit_are_refused_in_one_line_before_planning():
    """Each obstacle adds its own terms to the compiled program: 10^6 would never finish compiling, and 101 is past
    the largest count measured (driveopt.config.MAX_OBSTACLES); both are refused before the prior or the compiler."""
    statuses, errors = _cli_in_child(["plan", "--max-obstacles", "1000000", "--repeats", "0"],
                                     ["plan", "--samples", "60", "--max-obstacles", "101", "--repeats", "0"])
    assert statuses == [2, 2] and len(errors) == 2
    for error, count in zip(errors, ("1e+06", "101")):
        assert error.startswith(f"driveopt: error: obstacles a planning call is compiled for (max_obstacles) is {count}")
        assert "above the limit of 100; set DRIVEOPT_ALLOW_LARGE=1 to run it anyway" in error


def test_the_work_and_memory_estimates_count_the_obstacles(monkeypatch):
    """A configuration within the limits at the default 10 obstacles is refused against more obstacles: its work
    (samples x iterations x projection iterations x nodes) and its memory (samples x nodes) grow with them."""
    from driveopt.config import PlannerConfig, check_obstacles, check_planning_size

    monkeypatch.delenv("DRIVEOPT_ALLOW_LARGE", raising=False)
    heavy = PlannerConfig().replace(sampler={"num_iterations": 50}, projection={"max_iterations": 1000})  # 5e9 at 10
    wide = PlannerConfig().with_samples(100_000).replace(sampler={"num_iterations": 1},
                                                         projection={"max_iterations": 1})  # 1e7 sample-nodes at 10
    check_planning_size(heavy, 10)
    check_planning_size(wide, 10)
    with pytest.raises(ConfigError, match=r"planning work per call against 100 obstacles .* above the limit of 1e\+10"):
        check_planning_size(heavy, 100)
    with pytest.raises(ConfigError, match=r"planning memory per call against 30 obstacles .* above the limit of 2e\+07"):
        check_planning_size(wide, 30)
    monkeypatch.setenv("DRIVEOPT_ALLOW_LARGE", "1")
    check_planning_size(heavy, 100)
    check_planning_size(wide, 30)
    check_obstacles(10**6)  # opted in: the check passes (nothing is planned here)


def test_plan_refuses_a_problem_with_too_many_obstacles_without_compiling(monkeypatch):
    import jax

    from driveopt import planner
    from driveopt.problem import build_problem

    monkeypatch.setenv("DRIVEOPT_ALLOW_LARGE", "1")
    problem = build_problem(load_scene("static-blockage"), max_obstacles=101)
    monkeypatch.delenv("DRIVEOPT_ALLOW_LARGE")
    with pytest.raises(ConfigError, match="compiled for .* is 101"):
        build_problem(load_scene("static-blockage"), max_obstacles=101)

    def compiled(*args, **kwargs):
        raise AssertionError("plan compiled a call above the obstacle limit")

    monkeypatch.setattr(planner, "exported_solve", compiled)
    with pytest.raises(ConfigError, match="compiled for .* is 101"):
        planner.plan(problem, key=jax.random.PRNGKey(0))


def test_a_missing_problem_file_says_no_such_file_and_an_unknown_name_lists_the_builtins(tmp_path):
    with pytest.raises(ProblemError, match=r"nope\.json: no such file") as info:
        load_scene(tmp_path / "nope.json")
    assert not isinstance(info.value, UnknownProblemError)
    with pytest.raises(ProblemError, match="no such file"):
        load_scene("folder/no-suffix")
    with pytest.raises(UnknownProblemError, match="static-blockage"):
        load_scene("no-such-problem")


@pytest.mark.parametrize(
    "data, needle",
    [
        ({"ego": {**EGO, "vxx": 1}}, "unknown key(s) ['vxx'] in 'ego'; valid: ['ax', 'ay', 'length'"),
        ({"ego": {"x": 0, "y": 4}}, "'ego' is missing ['vx']"),
        ({"ego": EGO, "road": {"num_lane": 3}}, "unknown key(s) ['num_lane'] in 'road'; valid: ['curvature'"),
        ({"ego": EGO, "neighbours": [{"x": 1, "y": 0, "yawn": 0}]}, "unknown key(s) ['yawn'] in 'neighbours[0]'"),
        ({"ego": EGO, "neighbours": [{"x": 1}]}, "'neighbours[0]' is missing ['y']"),
        ({"ego": EGO, "neighbours": [{"x": 1, "y": 1e9}]}, "neighbours[0]: neighbour.y must be within"),
        ({"ego": EGO, "ellipse_margin": {"lateal": 1}}, "in 'ellipse_margin'; valid: ['lateral', 'longitudinal', 'time_gap']"),
        ({"ego": EGO, "slowing": -1.0}, "slowing must be within"),
    ],
)
def test_a_misspelt_or_missing_key_is_a_problem_error_listing_the_valid_keys(data, needle):
    with pytest.raises(ProblemError) as info:
        scene_from_dict(data)
    assert needle in str(info.value)


def test_a_scene_name_must_be_valid_unicode():
    with pytest.raises(ProblemError, match="not valid Unicode"):
        Scene(ego=scene_from_dict({"ego": EGO}).ego, name="\ud800")


@pytest.mark.parametrize("text, needle", [*BEYOND_THE_READER[:2], ('{"sampler": {"temperature": NaN}}', "NaN is not")])
def test_config_files_go_through_the_same_reader(tmp_path, text, needle):
    path = _write(tmp_path, text)
    with pytest.raises(UsageError, match=f"cannot read config {path}: .*{needle}"):
        config_overrides(str(path))


def test_a_missing_config_file_says_no_such_file(tmp_path):
    with pytest.raises(UsageError, match="no such file"):
        config_overrides(str(tmp_path / "nope.json"))


@pytest.mark.parametrize(
    "config, needle",
    [
        ({"basis": {"horizon": 1e-30}}, "basis.horizon must be in [1, 120] s"),
        ({"sampler": {"temperature": 1e-300}}, "sampler.temperature must be in [1e-06"),
    ],
)
def test_degenerate_config_values_are_refused_before_planning(tmp_path, capsys, config, needle):
    path = _write(tmp_path, json.dumps(config))
    with pytest.raises(ConfigError, match=needle.replace("[", r"\[")):
        config_overrides(str(path))
    assert needle in _one_line_error(capsys, ["plan", "--config", str(path), *FAST])


def test_a_roads_curvature_ahead_round_trips_through_a_problem_file_and_bad_ones_are_refused():
    import dataclasses

    from driveopt.problem import build_problem
    from driveopt.scene import CURVATURE_CELLS, Road, scene_to_dict

    cells = [0.0] * 20 + [0.05] * 30 + [-0.02] * (CURVATURE_CELLS - 50)  # signed: a left curve, then a right one
    scene = dataclasses.replace(load_scene("dense-snapshot"), road=Road(curvature_ahead=cells))
    again = scene_from_dict(json.loads(json.dumps(scene_to_dict(scene))))
    assert again == scene
    assert [round(float(c), 6) for c in build_problem(again).road_curvature] == cells
    assert "curvature_ahead" not in scene_to_dict(load_scene("dense-snapshot"))["road"]  # none given: none written
    gentle = dataclasses.replace(scene, slowing=1.5, slowing_from=25.0)
    assert scene_from_dict(json.loads(json.dumps(scene_to_dict(gentle)))) == gentle
    assert (float(build_problem(gentle).slowing), float(build_problem(gentle).slowing_from)) == (1.5, 25.0)
    for bad, message in (([0.01] * 3, "list of 80"), ("abc", "list of 80"), ([float("nan")] * CURVATURE_CELLS, "finite")):
        with pytest.raises(ProblemError, match=message):
            Road(curvature_ahead=bad)
