"""benchmarks/perf/derivative_bounds.py: residuals and extremes per side and iteration count, timings, the planner's picks
against the plain ones; bad runs are refused."""

from __future__ import annotations

import json

import pytest

from benchmarks.perf import derivative_bounds


@pytest.mark.slow  # compiles two planners
def test_a_small_run_records_every_side(tmp_path):
    out = tmp_path / "bounds.json"
    assert derivative_bounds.main(["--samples", "8", "--iterations", "2", "--calls", "1", "--keys", "1", "--pieces", "4",
                                   "--nearest", "1", "--problems", "static-blockage", "--json", str(out)]) == 0
    (case,) = json.loads(out.read_text())["cases"]
    (entry,) = case["residuals"]
    for side in ("nodes", "control_points/4", "nearest/1"):
        assert entry[side]["total"]["nonfinite"] == 0 and entry[side]["max_speed"] > 0
        assert 0 <= entry[side]["control_points_within_bounds"] <= 1 and case["timing_ms"][side] > 0
    assert set(case["plans"]["against_nodes"]) == {"control_points/4", "nearest/1", "nodes_other_key"}
    assert set(case["plans"]["picks"][0]) == {"nodes", "control_points/4", "nearest/1", "nodes_other_key"}


@pytest.mark.parametrize("argv", [["--pieces", "0", "--json", "x.json"], []])
def test_bad_runs_are_refused(argv):
    with pytest.raises(SystemExit) as stop:
        derivative_bounds.main(argv)
    assert stop.value.code == 2
