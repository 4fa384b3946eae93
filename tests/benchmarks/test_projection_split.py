"""benchmarks/perf/projection_split.py: every way projects the same batch to nearly the same coefficients; bad runs are refused."""

from __future__ import annotations

import json

import pytest

from benchmarks.perf import projection_split


def test_every_way_is_timed_and_projects_the_batch_as_the_whole_call(tmp_path):
    out = tmp_path / "split.json"
    assert projection_split.main(["--samples", "8", "--calls", "2", "--json", str(out)]) == 0
    cases = json.loads(out.read_text())["cases"]
    assert [c["way"] for c in cases] == list(projection_split.WAYS)
    assert [c["devices"] for c in cases] == [1, 1, 1, 2]
    assert cases[1]["cpus"] == 1
    for case in cases:
        assert case["median_ms"] > 0 and case["compile_s"] > 0
        assert case["max_abs_diff"] < 1.0  # the same projection, apart from rounding and each part's own early stop


@pytest.mark.parametrize("argv", [["--samples", "7", "--json", "x.json"], ["--calls", "0", "--json", "x.json"], []])
def test_bad_runs_are_refused_before_anything_compiles(capsys, argv):
    with pytest.raises(SystemExit) as stop:
        projection_split.main(argv)
    assert stop.value.code == 2 and "projection_split.py: error:" in capsys.readouterr().err
