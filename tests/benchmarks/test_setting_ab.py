"""benchmarks/studies/setting_ab.py: the rule a setting passes before it becomes a default, on hand-built pairs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks.studies import setting_ab


def episode(collided: bool = False, speed: float = 10.0) -> dict:
    return {"collided": collided, "off_road": False, "mean_speed": speed, "plan_ms": [20.0, 30.0]}


def test_identical_sides_pass():
    pairs = [(episode(), episode()) for _ in range(50)]
    verdict = setting_ab.judge(pairs)
    assert verdict["passed"] and verdict["mcnemar_p"] == 1.0 and verdict["speed_ratio"] == 1.0


def test_one_extra_collision_in_fifty_is_allowed_two_are_not():
    one = [(episode(), episode(collided=True))] + [(episode(), episode()) for _ in range(49)]
    two = [(episode(), episode(collided=True))] * 2 + [(episode(), episode()) for _ in range(48)]
    assert setting_ab.judge(one)["collisions_ok"]
    assert not setting_ab.judge(two)["collisions_ok"] and setting_ab.judge(two)["collisions"] == [0, 2]


def test_a_significantly_worse_side_fails_even_within_the_allowance():
    # 600 pairs allow 12 extra collisions: 20 only-changed against 8 only-own is 12 more, but McNemar finds it worse
    worse = [(episode(), episode(collided=True))] * 20 + [(episode(collided=True), episode())] * 8
    worse += [(episode(), episode())] * 572
    verdict = setting_ab.judge(worse)
    assert verdict["collisions"] == [8, 20] and verdict["collisions_allowed_extra"] == 12
    assert verdict["mcnemar_p"] < 0.05 and not verdict["collisions_ok"]


def test_speed_counts_only_pairs_where_neither_collided():
    pairs = [(episode(speed=10.0), episode(speed=9.7))] * 10 + [(episode(speed=10.0), episode(collided=True, speed=1.0))]
    verdict = setting_ab.judge(pairs)
    assert verdict["clean_pairs"] == 10 and verdict["speed_ratio"] == pytest.approx(0.97)
    assert not verdict["speed_ok"] and verdict["collisions_ok"] and not verdict["passed"]


def test_a_bad_override_is_refused_before_any_driving(tmp_path, capsys):
    config = tmp_path / "c.json"
    config.write_text(json.dumps({"projection": {"derivative_bounds": "everywhere"}}))
    with pytest.raises(SystemExit) as stop:
        setting_ab.main(["--config", str(config), "--out", str(tmp_path / "out")])
    assert stop.value.code == 2 and "derivative_bounds" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_upstream_pairs_take_the_resets_from_the_first_seed_on(tmp_path):
    for side in ("own", "changed"):
        folder = tmp_path / f"upstream-{side}"
        folder.mkdir()
        rows = [{"env": "roundabout-v0", "planner": "bilevel", "seed": s, **episode(speed=float(s))} for s in range(45)]
        rows.append({"env": "roundabout-v0", "planner": "bilevel", "seed": 21, "refused": "no lanes"})
        (folder / "episodes.jsonl").write_text("\n".join(json.dumps(r) for r in rows if side == "own" or r["seed"] != 22))
    pairs = setting_ab.upstream_pairs(tmp_path, "roundabout-v0", "bilevel", 20, first=20)
    assert [own["seed"] for own, _ in pairs] == [20, 21] + list(range(23, 40))  # 22 missing on one side, refusals left out
    assert all(own["seed"] == changed["seed"] for own, changed in pairs)


def test_a_changed_sample_count_drives_the_changed_side_at_that_count(tmp_path, monkeypatch):
    config = tmp_path / "c.json"
    config.write_text(json.dumps({"sampler": {"num_samples": 250}}))
    bench, upstream = [], []
    monkeypatch.setattr(setting_ab.subprocess, "run", lambda argv, check: bench.append(argv))
    monkeypatch.setattr(setting_ab.upstream_roads, "main", lambda argv: upstream.append(argv))
    monkeypatch.setattr(setting_ab, "bench_pairs", lambda *args: [(episode(), episode())] * 50)
    monkeypatch.setattr(setting_ab, "upstream_pairs", lambda *args: [(episode(), episode())] * 20)
    assert setting_ab.main(["--config", str(config), "--out", str(tmp_path / "out"), "--samples", "150"]) == 0

    def samples(argv):
        return argv[argv.index("--samples") + 1]

    assert [samples(argv) for argv in bench] == [samples(argv) for argv in upstream] == ["150", "250"]
    verdict = json.loads((tmp_path / "out" / "verdict.json").read_text())
    assert (verdict["samples"], verdict["changed_samples"], verdict["passed"]) == (150, 250, True)


def bench_record(speed: float, episode_index: int = 0) -> dict:
    return {"scenario": "four-lane-d3.0", "planner": "bilevel", "seed": 42, "episode": episode_index, "steps": 500,
            **episode(speed=speed)}


@pytest.mark.parametrize("speed_now, repeats", [(8.160419810104369, True), (8.160419810104371, False)])
def test_a_resumed_side_is_driven_again_and_refused_unless_it_repeats(tmp_path, monkeypatch, capsys, speed_now, repeats):
    config = tmp_path / "c.json"
    config.write_text(json.dumps({"projection": {"max_iterations": 12}}))
    own = tmp_path / "out" / "own"
    own.mkdir(parents=True)
    (own / "episodes.jsonl").write_text(json.dumps(bench_record(8.160419810104369)) + "\n"
                                        + json.dumps(bench_record(7.0, 1)) + "\n")
    driven = []

    def bench(argv, check):  # the scratch run writes what "this machine" drives; the sides' runs are recorded only
        out = Path(argv[argv.index("--out") + 1])
        driven.append((out, argv[argv.index("--episodes") + 1], argv[argv.index("--scenarios") + 1:argv.index("--planners")]))
        if out.name == "again":
            out.mkdir()
            (out / "episodes.jsonl").write_text(json.dumps(bench_record(speed_now)) + "\n")

    monkeypatch.setattr(setting_ab.subprocess, "run", bench)
    monkeypatch.setattr(setting_ab, "bench_pairs", lambda *args: [(episode(), episode())] * 50)
    argv = ["--config", str(config), "--out", str(tmp_path / "out"), "--upstream"]
    if repeats:
        assert setting_ab.main(argv) == 0
        assert [(out.name, n, roads) for out, n, roads in driven] == [
            ("again", "1", ["four-lane-d3.0"]), ("own", "50", ["four-lane-d3.0", "two-lane-d2.5"]),
            ("changed", "50", ["four-lane-d3.0", "two-lane-d2.5"])]  # the changed side held nothing: not driven again
    else:
        with pytest.raises(SystemExit) as stop:
            setting_ab.main(argv)
        assert "do not repeat on this machine" in str(stop.value) and "mean_speed 8.160419810104369 recorded" in str(stop.value)
        assert [out.name for out, _, _ in driven] == ["again"]  # refused before either side drives on


def test_only_the_first_episode_of_the_first_road_is_compared(tmp_path):
    folder = tmp_path / "upstream-own"
    folder.mkdir()
    rows = [{"env": "highway-v0", "planner": "bilevel", "seed": 0, "refused": "no lanes"},
            {"env": "highway-v0", "planner": "bilevel", "seed": 20, "steps": 20, **episode(speed=3.0)},
            {"env": "highway-v0", "planner": "idm", "seed": 20, "steps": 20, **episode(speed=4.0)}]
    (folder / "episodes.jsonl").write_text("\n".join(json.dumps(r) for r in rows))
    assert setting_ab.first_record(folder, "highway-v0", "bilevel", 20, upstream=True)["mean_speed"] == 3.0
    assert setting_ab.first_record(folder, "highway-v0", "bilevel", 0, upstream=True) is None
    assert setting_ab.first_record(tmp_path / "none", "highway-v0", "bilevel", 20, upstream=True) is None
    assert setting_ab.differences(rows[1], {**rows[1], "steps": 19}) == ["steps 20 recorded, 19 now"]
