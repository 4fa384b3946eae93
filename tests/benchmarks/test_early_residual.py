"""benchmarks/perf/early_residual.py: rank correlation and the elites halving keeps, against hand-built residuals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks.perf import early_residual


def test_a_perfect_early_ranking_keeps_every_elite_and_a_reversed_one_none():
    final = np.arange(8.0)
    assert early_residual.prediction(final * 3.0, final, elites=2) == {"spearman": 1.0, "kept_half": 1.0,
                                                                        "kept_quarter": 1.0}
    reversed_ = early_residual.prediction(final[::-1].copy(), final, elites=2)
    assert reversed_["spearman"] == -1.0 and reversed_["kept_half"] == 0.0 and reversed_["kept_quarter"] == 0.0


def test_kept_share_counts_the_elites_among_the_kept_rows():
    final = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0])
    early = np.array([0.0, 9.0, 1.0, 2.0, 3.0, 8.0, 8.5, 7.0])  # elite 1 ranks last early
    assert early_residual.kept_share(early, final, elites=2, keep=4) == 0.5
    assert early_residual.kept_share(early, final, elites=4, keep=2) is None, "a quarter below the elites is skipped"


@pytest.mark.slow
def test_a_small_run_records_each_early_count(tmp_path):
    out = tmp_path / "early.json"
    assert early_residual.main(["--samples", "8", "--early", "1", "--reference", "2", "--problems", "static-blockage",
                                "--json", str(out)]) == 0
    (case,) = json.loads(out.read_text())["cases"]
    assert list(case["early"]) == ["1"] and -1.0 <= case["early"]["1"]["spearman"] <= 1.0


def test_early_counts_at_or_beyond_the_reference_are_refused(capsys):
    with pytest.raises(SystemExit) as stop:
        early_residual.main(["--json", "x.json", "--early", "20", "--reference", "20"])
    assert stop.value.code == 2 and "below --reference" in capsys.readouterr().err
