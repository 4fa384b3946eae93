"""benchmarks/perf/sampler_drift.py: where the sampling distribution goes against the picks, both sides recorded."""

from __future__ import annotations

import json
import math

import pytest

from benchmarks.perf import sampler_drift
from driveopt.registry import get_optimiser


def test_records_both_sides_per_state_and_a_summary(tmp_path):
    out = tmp_path / "drift.json"
    assert sampler_drift.main(["--set", "early_iterations=6", "--states", "1", "--keys", "1", "--json", str(out)]) == 0
    record = json.loads(out.read_text())
    assert record["changed"] == {"early_iterations": 6} and len(record["states"]) == 1
    for side in ("own", "changed"):
        figures = record["summary"][side]
        assert set(figures) == set(sampler_drift.FIELDS)
        assert 0 <= figures["pick_speed"] <= 30 and 0 <= figures["final_mean_speed"] <= 30
        rows = get_optimiser("bilevel").config.sampler.num_samples + 3  # the samples, two stops, the previous plan
        assert 0 <= figures["first_feasible_rows"] <= rows and math.isfinite(figures["first_elites_speed"])
        assert 0 <= figures["first_infeasible_elite_weight"] <= 1


@pytest.mark.parametrize("argv", [["--set", "early_iterations=6", "--keys", "0"], ["--keys", "2"],
                                  ["--set", "early_iterations=6", "--states", "0"], ["--set", "no_such_field=1"],
                                  ["--set", "early_iterations=-1"]])
def test_bad_arguments_exit_with_a_message(argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        sampler_drift.main(argv)
    assert exit_.value.code == 2 and "error:" in capsys.readouterr().err
