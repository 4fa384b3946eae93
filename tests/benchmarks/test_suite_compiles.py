"""benchmarks/tools/suite_compiles.py: the plugin records each test's compilations and the graphs it looks up; the summary
merges the workers' files."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.tools import suite_compiles

REPOSITORY = Path(__file__).resolve().parents[2]  # benchmarks.tools.suite_compiles is imported from here

TESTS = '''
import jax
import jax.numpy as jnp

from driveopt.solve_export import ExportedCalls


def double(x):
    return 2 * x


def test_compiles():
    jax.jit(lambda x: x + 1)(jnp.ones(3)).block_until_ready()
    ExportedCalls(double, (), {})(jnp.ones(4))


def test_compiles_nothing():
    assert 1 + 1 == 2
'''


def test_the_plugin_counts_each_tests_compilations_and_graphs(tmp_path):
    (tmp_path / "test_tiny.py").write_text(TESTS)
    stats = tmp_path / "stats"
    env = {**os.environ, "COMPILE_STATS_DIR": str(stats), "PYTHONPATH": os.pathsep.join([str(REPOSITORY), *sys.path]),
           "DRIVEOPT_COMPILATION_CACHE": "0"}
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "benchmarks.tools.suite_compiles", "-p", "no:cacheprovider",
                          "-p", "no:xdist", "test_tiny.py"], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr
    text = suite_compiles.summary(stats, top=5)
    compiled = next(line for line in text.splitlines() if line.endswith("test_tiny.py::test_compiles"))
    assert int(compiled.split("(")[1].split(")")[0]) >= 2  # the test's jit and the exported call's graph
    assert "test_compiles_nothing" not in text  # no compilation, no row
    assert "1 planner graphs" in text and "double in 1 process(es), first by test_tiny.py::test_compiles" in text
    with pytest.raises(SystemExit, match="no compiles"):
        suite_compiles.summary(tmp_path / "empty", top=5)


def test_config_changes_name_every_changed_field():
    from driveopt.config import PlannerConfig

    changes = suite_compiles.config_changes
    config = PlannerConfig().replace(projection={"a_max": 4.5}, cost={"consistency": 1.0})
    assert changes(config, PlannerConfig()) == ["projection.a_max=4.5", "cost.consistency=1.0"]
    assert changes(PlannerConfig(), PlannerConfig()) == []
