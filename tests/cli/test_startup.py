"""The command line starts fast: ``--help``, every command's ``--help`` and the listings import neither JAX nor
highway-env nor Flax (they take seconds to load), and ``import driveopt`` loads its names on first use."""

import json
import os
import subprocess
import sys

import pytest

HEAVY = ("jax", "jaxlib", "highway_env", "gymnasium", "flax", "optax", "matplotlib", "torch")

# Runs the commands in one fresh interpreter and reports what each printed and which heavy modules got imported.
PROBE = r"""
import contextlib, io, json, sys
from driveopt.cli import main
out = []
for argv in json.loads(sys.argv[1]):
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        try:
            status = main(argv)
        except SystemExit as exc:  # --help
            status = exc.code
    out.append({"argv": argv, "status": status, "stdout": buffer.getvalue()})
print(json.dumps({"runs": out, "heavy": sorted(m for m in json.loads(sys.argv[2]) if m in sys.modules)}))
"""


def _probe(*commands: list[str]) -> dict:
    proc = subprocess.run([sys.executable, "-c", PROBE, json.dumps(commands), json.dumps(HEAVY)], capture_output=True,
                          text=True, timeout=120, env={**os.environ, "DRIVEOPT_COMPILATION_CACHE": "0"}, check=False)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.splitlines()[-1])


def test_import_driveopt_and_the_cli_load_no_heavy_module():
    code = (f"import sys, driveopt, driveopt.cli; print(sorted(m for m in {HEAVY!r} if m in sys.modules)); "
            "print(driveopt.__version__, len(dir(driveopt)) > 20)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == ["[]", "0.1.0 True"]


def test_help_and_listings_run_without_heavy_modules():
    commands = [["--help"], ["plan", "--help"], ["drive", "--help"], ["bench", "--help"], ["collect", "--help"],
                ["train", "--help"], ["train", "cvae", "--help"], ["train", "filter", "--help"], ["train", "ppo", "--help"],
                ["summarise", "--help"], ["plot-prior", "--help"], ["plot-curves", "--help"],
                ["scenarios"], ["planners"], ["problems"]]
    report = _probe(*commands)
    assert report["heavy"] == []
    runs = {" ".join(run["argv"]): run for run in report["runs"]}
    assert all(run["status"] == 0 for run in runs.values()), {k: r["status"] for k, r in runs.items()}
    top = runs["--help"]["stdout"]
    for command in ("plan", "problems", "drive", "bench", "summarise", "collect", "train", "scenarios", "planners"):
        assert command in top
    assert "--projection-iterations" in runs["plan --help"]["stdout"]
    assert "--scenario" in runs["drive --help"]["stdout"] and "--duration" in runs["drive --help"]["stdout"]
    assert "--latent" in runs["train cvae --help"]["stdout"]
    assert "four-lane-d3.0" in runs["scenarios"]["stdout"] and "bilevel" in runs["planners"]["stdout"]
    assert "static-blockage" in runs["problems"]["stdout"]


def test_every_commands_help_runs_without_heavy_modules():
    import argparse

    from driveopt.cli import build_parser

    def commands(parser, prefix):  # every subcommand, nested ones (train cvae, ...) included
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    yield [*prefix, name]
                    yield from commands(sub, [*prefix, name])

    every = list(commands(build_parser(), []))
    assert ["plan"] in every and ["train", "cvae"] in every
    report = _probe(*[[*command, "--help"] for command in every])
    assert report["heavy"] == []
    assert [run["status"] for run in report["runs"]] == [0] * len(every)


def test_lazy_exports_resolve_and_unknown_names_fail():
    import driveopt

    for name in driveopt.__all__:
        assert getattr(driveopt, name) is not None
    from driveopt import PlannerConfig, plan  # noqa: F401

    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        driveopt.no_such_name  # noqa: B018


def test_usage_errors_stay_one_line_without_heavy_modules():
    code = ("import sys\nfrom driveopt.cli import main\ntry:\n    main(['plan', '--samples', '0'])\n"
            f"except SystemExit as exc:\n    print(exc.code, sorted(m for m in {HEAVY!r} if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert proc.stdout.strip() == "2 []"
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("driveopt: error: argument --samples")


def test_planning_loads_no_simulator():
    """What ``driveopt plan`` imports to plan (the registry, whose drivers import the simulator's modules, and the
    planner) leaves highway-env, gymnasium, matplotlib and torch unloaded: a second ``plan`` starts in seconds."""
    code = ("import sys; from driveopt.registry import get_optimiser; import driveopt.planner, driveopt.problem; "
            f"get_optimiser('bilevel').prior(4); print(sorted(m for m in {HEAVY!r} if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == ["['jax', 'jaxlib']"]
