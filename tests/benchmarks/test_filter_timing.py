"""benchmarks/perf/filter_timing.py: every case plans with its own iteration count and filter, and bad options are refused."""

from __future__ import annotations

import json

import pytest

from benchmarks.perf import filter_timing as timing


def test_each_case_plans_with_its_iterations_and_only_the_learned_ones_with_a_filter_and_their_overrides(tmp_path, monkeypatch):
    seen = []
    real = timing.plan

    def recording_plan(problem, config, **kwargs):
        seen.append((config.projection.max_iterations, config.sampler.num_samples, config.projection.tolerance,
                     kwargs["safety_filter"] is not None))
        return real(problem, config, **kwargs)

    monkeypatch.setattr(timing, "plan", recording_plan)
    out = tmp_path / "t.json"
    learned_config = tmp_path / "learned.json"
    learned_config.write_text(json.dumps({"projection": {"tolerance": 0.01, "max_iterations": 50}}))
    assert timing.main(["--json", str(out), "--iterations", "2", "--reference", "2", "--calls", "2",
                        "--samples", "16", "--learned-config", str(learned_config)]) == 0
    report = json.loads(out.read_text())
    assert set(report["cases"]) == {"plain-2", "learned-2"}
    # one compile call and two round-robin calls per case, each with its own settings: the iteration count wins over
    # the learned cases' overrides, which the plain ones do not get
    assert sorted(set(seen)) == [(2, 16, 0.001, False), (2, 16, 0.01, True)]
    assert all(seen.count(case) == 3 for case in set(seen))
    for name, case in report["cases"].items():
        assert case["median_ms"] > 0 and case["p90_ms"] >= case["median_ms"] and case["compile_s"] >= 0
        assert report["share_of_reference"][name] == pytest.approx(case["median_ms"] / report["cases"]["plain-2"]["median_ms"])
    assert report["share_of_reference"]["plain-2"] == 1.0


@pytest.mark.parametrize("argv, needle", [
    (["--calls", "0"], "--calls"),
    (["--iterations", "25", "--reference", "100"], "--reference 100"),
    (["--iterations", "-1", "100"], "--iterations"),
    (["--filter-weights", "no-such.ckpt"], "no-such.ckpt"),
    (["--learned-config", "no-such.json"], "no-such.json"),
])
def test_bad_options_are_one_line_errors_and_write_nothing(tmp_path, capsys, argv, needle):
    out = tmp_path / "t.json"
    assert timing.main(["--json", str(out), "--samples", "16", "--calls", "1", *argv]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1
    assert not out.exists()
