"""benchmarks/p2_closed_loop.py: P2's closed-loop figures as resumable bench sweeps (issues 14 and 15)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
spec = importlib.util.spec_from_file_location("p2_closed_loop", BENCHMARKS / "p2_closed_loop.py")
SCRIPT = importlib.util.module_from_spec(spec)
spec.loader.exec_module(SCRIPT)


def test_the_figures_points_are_p2s_and_equal_runs_share_a_folder():
    fig8a, fig8b, fig7, fig9 = (SCRIPT.points(f) for f in ("fig8a", "fig8b", "fig7", "fig9"))
    assert sorted({p.x for p in fig8a}) == [10, 25, 50, 100] and sorted({p.x for p in fig8b}) == [250, 500, 750, 1000]
    assert {(p.variant, p.planner) for p in fig8a} == {("learned", "vqvae-filter"), ("plain", "vqvae")}
    assert all(p.scenario == "p2-four-lane-d3.0" for p in fig8a + fig8b)
    assert {p.episodes for p in fig8a if p.x != 100} == {30} and {p.episodes for p in fig8a if p.x == 100} == {50}
    # P2's 100 iterations at 1000 samples is one run, whichever figure asks for it
    assert {p.folder for p in fig8a if p.x == 100} == {p.folder for p in fig8b if p.x == 1000}
    assert {p.folder for p in fig9 if p.x == "3.0" and p.iterations is None} & {p.folder for p in fig7} == {
        "p2-four-lane-d3.0--cvae-filter--n1000--kdefault"}
    assert {p.iterations for p in fig9} == {None, 0} and {p.x for p in fig9} == {"1.0", "1.5", "3.0"}
    assert {p.scenario for p in fig7} == {"p2-four-lane-d3.0", "p2-four-lane-d1.5-slow"} and len(fig7) == 12
    references = [p for p in fig7 if p.samples is None]  # at their own sample counts, first (they are cheap)
    assert fig7[:4] == references and {p.planner for p in references} == {"bilevel-p1", "idm"}
    assert "p2-four-lane-d3.0--bilevel-p1--ndefault--kdefault" in {p.folder for p in references}
    assert SCRIPT.bench_spec(references[0], {"vqvae": "p.ckpt", "cvae": "c.ckpt"}, None).options == {}
    assert {p.episodes for p in SCRIPT.points("fig9", episodes=3)} == {3}
    pair = SCRIPT.points("fig7", episodes=10, planners=["vqvae", "cvae-filter"])  # a first look: the same folders
    assert sorted(p.folder for p in pair) == sorted(p.folder for p in fig7 if p.planner in ("vqvae", "cvae-filter"))
    assert [p.planner for p in pair] == ["vqvae"] * 2 + ["cvae-filter"] * 2  # in the order asked for
    assert {p.episodes for p in pair} == {10}
    dense = SCRIPT.points("fig7", planners=["vqvae", "bilevel-p1"], scenarios=["p2-four-lane-d3.0"])
    assert [p.folder for p in dense] == ["p2-four-lane-d3.0--vqvae--n1000--kdefault",
                                         "p2-four-lane-d3.0--bilevel-p1--ndefault--kdefault"]
    with pytest.raises(SCRIPT.DriveoptError, match="no points on two-lane-d2.5"):
        SCRIPT.points("fig7", scenarios=["two-lane-d2.5"])
    target = SCRIPT.points("fig8a", planners=["vqvae-filter", "vqvae"], xs=["25", "100"])  # the pair first
    assert [p.folder for p in target] == ["p2-four-lane-d3.0--vqvae-filter--n1000--k25",
                                          "p2-four-lane-d3.0--vqvae-filter--n1000--kdefault",
                                          "p2-four-lane-d3.0--vqvae--n1000--k25", "p2-four-lane-d3.0--vqvae--n1000--kdefault"]
    with pytest.raises(SCRIPT.DriveoptError, match="fig8a has no points at 20; its values: 10, 100, 25, 50"):
        SCRIPT.points("fig8a", xs=["20"])


def test_a_points_bench_run_carries_its_weights_iterations_and_filter():
    point = SCRIPT.Point("p2-four-lane-d3.0", "vqvae-filter", 500, 25, 30, "learned", 25)
    weights = {"cvae": "c.ckpt", "vqvae": "p.ckpt", "filter": "f.ckpt"}
    run = SCRIPT.bench_spec(point, weights, None)
    assert run.planners == ("vqvae-filter",) and run.episodes == 30
    assert run.options == {"samples": 500, "weights": "p.ckpt",
                           "config": {"projection": {"max_iterations": 25}, "safety_filter": {"weights": "f.ckpt"}}}
    plain = SCRIPT.bench_spec(point._replace(planner="cvae-filter", iterations=None), weights, 2.0)
    assert plain.options == {"samples": 500, "weights": "c.ckpt", "duration": 2.0}


def test_a_sweep_runs_writes_its_table_and_plot_and_resumes(tmp_path, monkeypatch):
    # idm ignores samples and config (no compilation): the sweep machinery is what is tested here
    tiny = [SCRIPT.Point("two-lane-d1.0", "idm", 20, k, 1, "plain", k or 5) for k in (None, 2)]
    monkeypatch.setattr(SCRIPT, "points", lambda figure, episodes=None, planners=None, scenarios=None, xs=None: tiny)
    argv = ["--figure", "fig8a", "--out", str(tmp_path), "--workers", "1", "--duration", "0.3"]
    assert SCRIPT.main(argv) == 0
    table = json.loads((tmp_path / "fig8a.json").read_text())
    assert [r["folder"] for r in table] == [p.folder for p in tiny]
    assert all(r["episodes"] == 1 and 0.0 <= r["collision_rate"] <= 1.0 for r in table)
    assert (tmp_path / "fig8a.png").stat().st_size > 0
    lines = {p.folder: (tmp_path / p.folder / "episodes.jsonl").read_text() for p in tiny}
    assert SCRIPT.main(argv) == 0  # everything done: nothing reruns
    assert {p.folder: (tmp_path / p.folder / "episodes.jsonl").read_text() for p in tiny} == lines


def test_records_carry_a_sweep_to_a_new_output_folder(tmp_path, monkeypatch):
    tiny = [SCRIPT.Point("two-lane-d1.0", "idm", 20, None, 1, "plain", 5)]
    monkeypatch.setattr(SCRIPT, "points", lambda figure, episodes=None, planners=None, scenarios=None, xs=None: tiny)
    records = tmp_path / "records"
    argv = ["--figure", "fig8a", "--workers", "1", "--duration", "0.3", "--records", str(records)]
    assert SCRIPT.main([*argv, "--out", str(tmp_path / "first")]) == 0
    kept = (records / tiny[0].folder / "episodes.jsonl").read_text()
    assert kept == (tmp_path / "first" / tiny[0].folder / "episodes.jsonl").read_text() and kept.strip()
    assert SCRIPT.main([*argv, "--out", str(tmp_path / "second")]) == 0  # another machine: resumes from the records
    assert (tmp_path / "second" / tiny[0].folder / "episodes.jsonl").read_text() == kept  # nothing rerun or repeated


@pytest.mark.parametrize("argv, needle", [
    (["--figure", "fig7", "--cvae-weights", "missing.ckpt"], "missing.ckpt does not exist"),
    (["--figure", "fig8a", "--episodes", "0"], "--episodes must be at least 1"),
    (["--figure", "fig7", "--planners", "vqvae", "vqvae-filter"], "fig7 has no points of vqvae-filter; its planners: bilevel-p1, cvae, cvae-filter, idm, vqvae, vqvae-cem"),
])
def test_bad_options_stop_the_sweep_before_it_runs(tmp_path, capsys, argv, needle):
    assert SCRIPT.main([*argv, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_list_prints_every_point(capsys):
    assert SCRIPT.main(["--figure", "fig9", "--out", "unused", "--list"]) == 0
    assert len(capsys.readouterr().out.strip().splitlines()) == 12


def test_stalls_count_slow_episodes_where_the_reference_drives_on(tmp_path):
    """An episode finished under 2.5 m/s is a stall where bilevel-p1 finishes the same one above 6 m/s; collided
    episodes (either side) and episodes beyond the point's count are not compared."""
    def folder(name, records):
        (tmp_path / name).mkdir()
        (tmp_path / name / "episodes.jsonl").write_text(
            "".join(json.dumps({"episode": e, "collided": c, "mean_speed": v}) + "\n" for e, c, v in records))
        return tmp_path / name

    planner = folder("p", [(0, False, 1.0), (1, False, 2.0), (2, True, 0.5), (3, False, 2.4), (4, False, 7.0), (5, False, 1.0)])
    reference = folder("r", [(0, False, 8.0), (1, False, 5.0), (2, False, 9.0), (3, True, 9.0), (4, False, 9.0), (5, False, 9.0)])
    speeds = SCRIPT.episode_speeds(planner, episodes=5)
    assert speeds == {0: 1.0, 1: 2.0, 2: None, 3: 2.4, 4: 7.0}
    assert SCRIPT.stalls(speeds, SCRIPT.episode_speeds(reference, 50)) == (1, 3)  # episode 0; compared 0, 1, 4
