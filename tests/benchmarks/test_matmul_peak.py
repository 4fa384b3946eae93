"""benchmarks/perf/matmul_peak.py: a positive rate from the stated work; bad runs are refused."""

from __future__ import annotations

import json

import pytest

from benchmarks.perf import matmul_peak


def test_the_rate_is_the_chain_s_work_over_its_median_time(tmp_path):
    out = tmp_path / "peak.json"
    assert matmul_peak.main(["--calls", "3", "--json", str(out)]) == 0
    record = json.loads(out.read_text())
    flops = 2 * matmul_peak.ROWS * matmul_peak.WIDTH ** 2 * matmul_peak.CHAIN
    assert record["gflop_per_s"] == pytest.approx(flops / (record["median_ms"] / 1e3) / 1e9, rel=1e-2)
    assert record["processor"]  # rates are comparable only on one processor model


@pytest.mark.parametrize("argv", [["--calls", "0", "--json", "x.json"], []])
def test_bad_runs_are_refused(capsys, argv):
    with pytest.raises(SystemExit) as stop:
        matmul_peak.main(argv)
    assert stop.value.code == 2 and "matmul_peak.py: error:" in capsys.readouterr().err
