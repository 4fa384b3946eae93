"""benchmarks/perf/projection_variants.py: every variant is timed on the same batch and projects it; bad runs are refused."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks.perf import projection_variants


def test_the_variants_change_what_they_name_and_only_that():
    realtime = projection_variants.VARIANTS["realtime"][1]
    for name, (slots, cfg) in projection_variants.VARIANTS.items():
        changed = {field for field in ("nearest_obstacles", "nearest_choice", "anderson_window", "derivative_bounds",
                                       "max_iterations", "obstacle_stride") if getattr(cfg, field) != getattr(realtime, field)}
        expected = {"batch-nearest-4": {"nearest_obstacles", "nearest_choice"},
                    "batch-nearest-5": {"nearest_obstacles", "nearest_choice"}, "sample-nearest-4": {"nearest_obstacles"},
                    "no-anderson": {"anderson_window"}, "plain-nodes": {"anderson_window", "derivative_bounds"},
                    "no-iterations": {"max_iterations"}, "obstacle-stride-4": {"obstacle_stride"}}.get(name, set())
        assert changed == expected, name
        assert slots == {"4-slots": 4, "1-slot": 1}.get(name, 10)
    assert realtime.tolerance == 0.0  # fixed work per call


@pytest.mark.slow  # nine projections compiled (about a minute)
def test_every_variant_is_timed(tmp_path):
    out = tmp_path / "variants.json"
    assert projection_variants.main(["--samples", "8", "--rounds", "2", "--json", str(out)]) == 0
    results = json.loads(out.read_text())["results"]["8"]
    assert list(results) == list(projection_variants.VARIANTS)
    for result in results.values():
        assert result["median_ms"] > 0 and np.isfinite(result["median_residual"])


def test_a_subset_of_the_variants_is_timed_in_the_order_given(tmp_path):
    out = tmp_path / "variants.json"
    assert projection_variants.main(["--samples", "8", "--rounds", "1", "--json", str(out),
                                     "--variants", "no-iterations", "realtime"]) == 0
    assert list(json.loads(out.read_text())["results"]["8"]) == ["no-iterations", "realtime"]


@pytest.mark.parametrize("argv", [["--samples", "0", "--json", "x.json"], ["--rounds", "0", "--json", "x.json"], [],
                                  ["--variants", "fast", "--json", "x.json"]])
def test_bad_runs_are_refused_before_anything_compiles(capsys, argv):
    with pytest.raises(SystemExit) as stop:
        projection_variants.main(argv)
    assert stop.value.code == 2 and "projection_variants.py: error:" in capsys.readouterr().err
