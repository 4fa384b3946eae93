"""benchmarks/perf/kernel_profile.py: a trace's kernels, per call and by how often a call runs them; and a profile of the
planner's own executable whose loops show up as groups."""

from __future__ import annotations

import json

import jax
import pytest

from driveopt import planner

from benchmarks.perf import kernel_profile


def test_kernels_are_timed_per_call_and_grouped_by_runs():
    events = [
        {"ph": "X", "name": "fusion.1", "dur": 30.0}, {"ph": "X", "name": "fusion.1", "dur": 50.0},
        {"ph": "X", "name": "dot.2", "dur": 10.0}, {"ph": "X", "name": "dot.2", "dur": 10.0},
        {"ph": "X", "name": "dot.2", "dur": 10.0}, {"ph": "X", "name": "dot.2", "dur": 10.0},
        {"ph": "X", "name": "copy.3", "dur": 4.0},
        {"ph": "i", "name": "fusion.1", "dur": 999.0},  # not a complete event
        {"ph": "X", "name": "$planner.py:423 plan", "dur": 500.0}, {"ph": "X", "name": "ThunkExecutor::Execute", "dur": 90.0},
        {"ph": "X", "name": "PjitFunction(solve)", "dur": 80.0}, {"ph": "X", "name": "end: fusion.1", "dur": 1.0},
    ]
    kernels = kernel_profile.kernel_times(events, calls=2)
    assert kernels == [{"kernel": "fusion.1", "us_per_call": 40.0, "runs_per_call": 1.0},
                       {"kernel": "dot.2", "us_per_call": 20.0, "runs_per_call": 2.0},
                       {"kernel": "copy.3", "us_per_call": 2.0, "runs_per_call": 0.5}]
    grouped = kernel_profile.groups(kernels)
    assert [g["runs_per_call"] for g in grouped] == [1.0, 2.0, 0.5]
    assert grouped[0] == {"runs_per_call": 1.0, "kernels": 1, "ms_per_call": pytest.approx(0.04)}


@pytest.mark.slow
def test_a_planner_profile_shows_its_projection_loop(tmp_path, monkeypatch):
    monkeypatch.setattr(planner, "XLA_CPU_COMPILER_OPTIONS", dict(planner.XLA_CPU_COMPILER_OPTIONS))  # main() adds to it
    cache = jax.config.jax_enable_compilation_cache  # main() turns the persistent cache off
    out = tmp_path / "kernels.json"
    try:
        assert kernel_profile.main(["--json", str(out), "--samples", "16", "--calls", "1", "--fixed-work"]) == 0
    finally:
        jax.config.update("jax_enable_compilation_cache", cache)
        planner.exported_solve.cache_clear()  # later tests build the planner's jit without the annotations
    report = json.loads(out.read_text())
    assert report["planner"] == "bilevel" and report["samples"] == 16 and report["call_ms"] > 0
    assert len(report["load_before"]) == 3 and report["kernels"]
    assert report["kernel_sum_ms"] == pytest.approx(sum(k["us_per_call"] for k in report["kernels"]) / 1e3)
    # bilevel: 5 sampler iterations of its projection's iterations, the first sampler iteration outside the sampler's scan
    from driveopt.registry import get_planner

    config = get_planner("bilevel").config
    projection, later = config.projection.max_iterations, config.sampler.num_iterations - 1
    runs = {g["runs_per_call"] for g in report["groups"]}
    assert {float(projection), float(projection * later)} <= runs
