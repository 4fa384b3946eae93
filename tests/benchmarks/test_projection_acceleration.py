"""benchmarks/perf/projection_acceleration.py: residuals both ways at every iteration count, the iterations to reach the
plain residual, timings; bad runs are refused."""

from __future__ import annotations

import json

import pytest

from benchmarks.perf import projection_acceleration


@pytest.mark.slow
def test_a_small_run_records_both_sides(tmp_path):
    out = tmp_path / "acceleration.json"
    assert projection_acceleration.main(["--samples", "8", "--iterations", "1", "--reference", "2", "--calls", "1",
                                         "--problems", "static-blockage", "--json", str(out)]) == 0
    (case,) = json.loads(out.read_text())["cases"]
    assert [r["iterations"] for r in case["residuals"]] == [1, 2]
    for r in case["residuals"]:
        assert r["plain"]["nonfinite"] == r["accelerated"]["nonfinite"] == 0
    assert case["to_reach"] in (1, 2, None)
    assert case["timing_ms"]["plain"] > 0 and case["timing_ms"]["accelerated"] > 0


@pytest.mark.parametrize("argv", [["--samples", "0", "--json", "x.json"], []])
def test_bad_runs_are_refused(capsys, argv):
    with pytest.raises(SystemExit) as stop:
        projection_acceleration.main(argv)
    assert stop.value.code == 2
