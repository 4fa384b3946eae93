import json

import pytest

from driveopt.cli import main

FAST = ["--samples", "120", "--iterations", "2", "--projection-iterations", "10", "--repeats", "1"]


def _refuse(name):
    raise ValueError(f"{name} is not JSON")


def test_plan_writes_json_and_plot(tmp_path, capsys):
    out, fig = tmp_path / "r.json", tmp_path / "r.png"
    # grid: the configuration test_plan_speaks_the_registered_planner_names compiles too (one compilation for both)
    assert main(["plan", "--problem", "static-blockage", "--planner", "grid", "--repeats", "1", "--json", str(out),
                 "--plot", str(fig)]) == 0
    report = json.loads(out.read_text(), parse_constant=_refuse)  # strict JSON: no NaN or Infinity
    assert report["status"] in ("SUCCESS", "INFEASIBLE")
    traj = report["trajectory"]
    assert set(("t", "x", "y", "speed", "heading")) <= set(traj) and len(traj["x"]) == 100
    assert len(report["setpoints"]["speed"]) == 4 and len(report["setpoints"]["lateral"]) == 4
    assert set(report["residuals"]) == {"obstacle", "velocity", "acceleration", "lane", "total"}
    assert "speed" in report["costs"] and "total" in report["costs"]
    assert report["timing"]["compile_s"] >= 0 and report["timing"]["solve_s"] > 0
    problem = report["problem"]
    assert {"x", "y", "vx", "vy", "length", "width"} <= set(problem["neighbours"][0])
    assert problem["ego"]["vx"] == 15.0 and problem["road"]["num_lanes"] == 4
    assert fig.stat().st_size > 10_000
    assert "static-blockage" in capsys.readouterr().out


@pytest.mark.parametrize(
    "content, needle",
    [
        ("{not json", "not valid JSON"),
        ('{"ego": {"x": 0, "y": 4}}', "ego"),
        ('{"ego": {"x": 0, "y": 4, "vx": "fast"}}', "ego.vx"),
        ('{"ego": {"x": 0, "y": 4, "vx": 10}, "neighbours": [{"x": NaN, "y": 0}]}', "finite"),
        ('{"ego": {"x": 0, "y": 4, "vx": 10}, "speed_limit": 3}', "unknown key"),
        ('[1, 2]', "JSON object"),
    ],
)
def test_bad_problem_file_is_one_line_error(tmp_path, capsys, content, needle):
    bad = tmp_path / "bad.json"
    bad.write_text(content)
    assert main(["plan", "--problem", str(bad), *FAST]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("driveopt: error:") and needle in err and "\n" not in err


def test_unknown_problem_lists_builtins(capsys):
    assert main(["plan", "--problem", "no-such-problem"]) == 2
    err = capsys.readouterr().err
    assert "static-blockage" in err and "dense-snapshot" in err


def test_bad_config_file(tmp_path, capsys):
    cfg = tmp_path / "cfg.json"
    cfg.write_text('{"sampler": {"num_samplez": 10}}')
    assert main(["plan", "--config", str(cfg), *FAST]) == 2
    assert "num_samplez" in capsys.readouterr().err


def test_plan_speaks_the_registered_planner_names(tmp_path, capsys):
    out = tmp_path / "grid.json"
    assert main(["plan", "--problem", "dense-snapshot", "--planner", "grid", "--repeats", "0", "--json", str(out)]) == 0
    report = json.loads(out.read_text(), parse_constant=_refuse)
    assert report["timing"]["solve_s"] is None and report["timing"]["compile_s"] is None  # --repeats 0: null, not NaN
    assert report["planner"] == "grid" and report["config"]["sampler"]["num_iterations"] == 1  # grid's own config
    assert report["config"]["sampler"]["num_samples"] == 320
    assert main(["plan", "--planner", "idm"]) == 2  # no optimiser behind it
    assert "optimisers: bilevel" in capsys.readouterr().err
    assert main(["plan", "--planner", "mpc-magic"]) == 2
    assert "valid planners" in capsys.readouterr().err


def test_a_programming_error_is_not_reported_as_a_usage_error(monkeypatch):
    """Only DriveoptError becomes the one-line exit 2; a bug keeps its traceback."""
    import driveopt.cli.listing as listing

    def broken(args):
        raise ValueError("an internal invariant broke")

    monkeypatch.setattr(listing, "run_planners", broken)
    with pytest.raises(ValueError, match="internal invariant"):
        main(["planners"])


@pytest.mark.parametrize("command", [["plan"], ["plan", "--planner", "cvae"], ["drive", "--planner", "cvae"],
                                     ["drive", "--planner", "dqn"], ["drive"]])
def test_weights_that_are_not_a_file_are_refused_in_one_line(tmp_path, capsys, command):
    """A mistyped --weights or --filter-weights path is named before any planning, whichever planner is asked for."""
    for option in ("--weights", "--filter-weights"):
        if option == "--filter-weights" and "dqn" in command:
            continue  # dqn takes no filter weights: refused for that, below
        assert main([*command, option, str(tmp_path / "missing.ckpt")]) == 2
        err = capsys.readouterr().err.strip()
        what = "weights" if option == "--weights" else "filter weights"
        assert err == f"driveopt: error: {what} file {tmp_path / 'missing.ckpt'} does not exist"


@pytest.mark.parametrize("command, name", [(["plan"], "bilevel"), (["plan", "--planner", "grid"], "grid"),
                                           (["drive", "--planner", "bilevel"], "bilevel"),
                                           (["drive", "--planner", "idm"], "idm")])
def test_weights_for_a_planner_without_a_learned_prior_are_refused(tmp_path, capsys, command, name):
    """bilevel's Gaussian prior (or grid's, or idm) reads no checkpoint: --weights is an error, not ignored."""
    given = tmp_path / "given.ckpt"
    given.write_bytes(b"weights")
    assert main([*command, "--weights", str(given)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"driveopt: error: planner {name} takes no weights") and "\n" not in err
    if name == "idm":
        assert main([*command, "--filter-weights", str(given)]) == 2
        assert "planner idm takes no filter weights" in capsys.readouterr().err
