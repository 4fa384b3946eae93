"""Bench harness: resume without loss or duplicates, parallel workers, summary statistics."""

import dataclasses
import json
import os
import re
import threading

import numpy as np
import pytest

from driveopt.errors import DriveoptError
from driveopt.experiments.bench import BenchOptionError, BenchSpec, run_bench
from driveopt.experiments.runner import cpu_shares, execute
from driveopt.experiments.store import JobKey, StoreError, key_of, load_records
from driveopt.experiments.summary import markdown_table, summarise, wilson_interval


class Interrupt(Exception):
    pass


def fake_episode(job, options):
    """Deterministic stand-in for a simulated episode (keeps the harness test fast)."""
    crashed = (job.env_seed + len(job.planner)) % 4 == 0
    return {"collided": crashed, "off_road": False, "mean_speed": 10.0 + job.episode,
            "plan_ms": [1.0, 2.0, 3.0], "sim_seconds": 0.1, "plan_seconds": 0.2, "steps": 3}


COUNT = {"n": 0}


def interrupting_episode(job, options):
    COUNT["n"] += 1
    if COUNT["n"] > options["stop_after"]:
        raise Interrupt()
    return fake_episode(job, options)


SPEC = BenchSpec(scenarios=("two-lane-d1.0", "four-lane-d3.0"), planners=("grid", "bilevel"), seeds=(42, 123), episodes=3)


def test_interrupted_run_resumes_without_loss_or_duplicates(tmp_path):
    spec = BenchSpec(SPEC.scenarios, SPEC.planners, SPEC.seeds, SPEC.episodes, {"stop_after": 5})
    COUNT["n"] = 0
    with pytest.raises(Interrupt):
        run_bench(spec, tmp_path, workers=1, episode_fn=interrupting_episode, progress=False)
    assert len(load_records(tmp_path / "episodes.jsonl")) == 5
    # Simulate a crash in the middle of writing a line.
    with open(tmp_path / "episodes.jsonl", "a") as f:
        f.write('{"schema": 1, "scenario": "two-l')
    rows = run_bench(spec, tmp_path, workers=1, episode_fn=fake_episode, progress=False)
    records = load_records(tmp_path / "episodes.jsonl")
    keys = [(r["scenario"], r["planner"], r["seed"], r["episode"]) for r in records]
    assert len(keys) == len(set(keys)) == len(spec.jobs()) == 24
    assert sum(r["episodes"] for r in rows) == 24
    assert (tmp_path / "summary.md").read_text().count("\n") == 2 + 4
    assert (tmp_path / "summary.png").stat().st_size > 5000


def test_a_run_stopped_in_its_workers_leaves_no_pool_thread_behind():
    """The pool's manager thread has ended when the exception leaves ``execute``: one still running at interpreter exit
    races concurrent.futures' exit hook, which then prints a traceback after the command's last line."""
    from concurrent.futures.process import _ExecutorManagerThread

    def stop(record):
        raise Interrupt()

    with pytest.raises(Interrupt):
        execute(SPEC.jobs(), {}, fake_episode, stop, workers=2)
    assert not [t for t in threading.enumerate() if isinstance(t, _ExecutorManagerThread) and t.is_alive()]


def test_parallel_workers_give_the_same_records_as_serial(tmp_path):
    serial = run_bench(SPEC, tmp_path / "a", workers=1, episode_fn=fake_episode, progress=False)
    parallel = run_bench(SPEC, tmp_path / "b", workers=2, episode_fn=fake_episode, progress=False)
    assert serial == parallel
    a = sorted(json.dumps(r, sort_keys=True) for r in load_records(tmp_path / "a" / "episodes.jsonl"))
    b = sorted(json.dumps(r, sort_keys=True) for r in load_records(tmp_path / "b" / "episodes.jsonl"))
    assert a == b


def cpus_episode(job, options):
    """The worker's process id and the CPUs it may run on."""
    return {"pid": os.getpid(), "cpus": sorted(os.sched_getaffinity(0))}


def test_cpu_shares_split_the_cpus_into_disjoint_near_equal_parts():
    shares = cpu_shares(range(16), 3)
    assert [len(s) for s in shares] == [6, 5, 5]
    assert sorted(c for s in shares for c in s) == list(range(16))
    assert cpu_shares({3, 1}, 2) == [(1,), (3,)]
    assert cpu_shares(range(2), 3) == []  # more workers than CPUs: left unbound


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity"), reason="CPU affinity is Linux-only")
def test_each_worker_runs_on_its_own_share_of_the_cpus():
    parent = sorted(os.sched_getaffinity(0))
    records = []
    jobs = [JobKey("s", "p", 0, episode) for episode in range(6)]
    execute(jobs, {}, cpus_episode, records.append, workers=2)
    by_worker = {r["pid"]: tuple(r["cpus"]) for r in records}
    assert len(records) == 6 and len(by_worker) <= 2
    if len(parent) >= 2:
        assert set(by_worker.values()) <= set(cpu_shares(parent, 2))
        assert len(set(by_worker.values())) == len(by_worker)  # two workers never share a CPU
    else:
        assert set(by_worker.values()) == {tuple(parent)}


def test_corrupted_results_file_is_reported(tmp_path):
    (tmp_path / "episodes.jsonl").write_text('garbage\n{"schema": 1}\n')
    with pytest.raises(StoreError, match="corrupted"):
        run_bench(SPEC, tmp_path, workers=1, episode_fn=fake_episode, progress=False)


def test_resuming_with_other_options_is_refused(tmp_path):
    """Extending a sweep (more planners, episodes) is a resume; changing how episodes run is not."""
    run_bench(SPEC, tmp_path, workers=1, episode_fn=fake_episode, progress=False)
    more = BenchSpec(SPEC.scenarios, SPEC.planners + ("random",), SPEC.seeds, SPEC.episodes + 1)
    run_bench(more, tmp_path, workers=1, episode_fn=fake_episode, progress=False)
    assert len(load_records(tmp_path / "episodes.jsonl")) == len(more.jobs())
    other = BenchSpec(SPEC.scenarios, SPEC.planners, SPEC.seeds, SPEC.episodes, {"config": {"cost": {"consistency": 1.0}}})
    with pytest.raises(StoreError, match="other output folder"):
        run_bench(other, tmp_path, workers=1, episode_fn=fake_episode, progress=False)
    assert len(load_records(tmp_path / "episodes.jsonl")) == len(more.jobs())


def test_unknown_backend(tmp_path):
    with pytest.raises(ValueError, match="valid: local, ray"):
        run_bench(SPEC, tmp_path, backend="slurm", episode_fn=fake_episode, progress=False)


def test_summary_statistics():
    records = [{"scenario": "s", "planner": "p", "collided": i < 2, "off_road": i == 3, "mean_speed": float(i),
                "plan_ms": [10.0 * i], "sim_seconds": 1.0, "plan_seconds": 2.0} for i in range(10)]
    (row,) = summarise(records)
    assert row["collision_rate"] == 0.2 and row["off_road_rate"] == 0.1
    assert row["mean_speed_collision_free"] == pytest.approx(sum(range(2, 10)) / 8)
    assert row["mean_speed_all"] == pytest.approx(4.5)
    low, high = wilson_interval(2, 10)
    assert row["collision_ci_low"] == low and 0.05 < low < 0.2 < high < 0.52
    assert wilson_interval(0, 50)[0] == 0.0 and wilson_interval(0, 50)[1] < 0.08
    for n in range(1, 60):  # every run collided (or none did): the interval still holds the rate
        assert wilson_interval(n, n)[1] == 1.0 and wilson_interval(0, n)[0] == 0.0
    assert row["speed_std_collision_free"] == pytest.approx(float(np.std(np.arange(2, 10))))
    assert row["reference"] == "" and markdown_table([row]).splitlines()[-1].endswith("| 1.0 + 2.0 |")  # sim + plan
    (crashed,) = summarise([dict(r, collided=True) for r in records])  # no collision-free episode: no speed, not "nan"
    assert "| 1.00 (0.72-1.00) | - | 4.50 |" in markdown_table([crashed])


def test_plan_times_come_only_from_episodes_planned_on_the_cpu():
    """A point may hold episodes run on an accelerator for their outcomes: they count in every rate and speed,
    but the plan-time and wall-time columns are the CPU episodes' (records without a device ran on the CPU)."""
    old = {"scenario": "s", "planner": "p", "collided": False, "off_road": False, "mean_speed": 5.0,
           "plan_ms": [100.0, 300.0], "sim_seconds": 1.0, "plan_seconds": 2.0}
    cpu = [old, {**old, "device": "cpu", "plan_ms": [200.0]}]
    gpu = {**old, "device": "gpu", "collided": True, "plan_ms": [1.0] * 9, "sim_seconds": 9.0, "plan_seconds": 9.0}
    (row,) = summarise(cpu + [gpu])
    assert row["episodes"] == 3 and row["collision_rate"] == pytest.approx(1 / 3)
    assert row["plan_ms_median"] == 200.0 and row["sim_s_per_episode"] == 1.0 and row["plan_s_per_episode"] == 2.0
    (untimed,) = summarise([gpu])
    assert np.isnan(untimed["plan_ms_median"]) and markdown_table([untimed]).splitlines()[-1].endswith("| - / - | - + - |")


def test_planners_are_compared_with_the_reference_on_the_same_episodes():
    """Only episodes the reference also ran (same scenario, seed, episode) and neither collided in count."""
    def record(planner, episode, speed, collided=False, scenario="s"):
        return {"scenario": scenario, "planner": planner, "seed": 42, "episode": episode, "collided": collided,
                "off_road": False, "mean_speed": speed, "plan_ms": [], "sim_seconds": 1.0, "plan_seconds": 0.0}
    records = [record("idm", 0, 8.0), record("idm", 1, 8.0), record("idm", 2, 8.0, collided=True), record("idm", 3, 8.0),
               record("p", 0, 9.0), record("p", 1, 7.0), record("p", 2, 9.0), record("p", 3, 9.0, collided=True),
               record("p", 4, 9.0), record("p", 0, 1.0, scenario="other")]
    rows = {(r["scenario"], r["planner"]): r for r in summarise(records)}
    p = rows[("s", "p")]
    assert (p["faster_than_reference"], p["compared_with_reference"], p["reference"]) == (1, 2, "idm")
    assert "| 1/2 (idm) |" in markdown_table([p])
    assert rows[("other", "p")]["reference"] == "" and rows[("s", "idm")]["compared_with_reference"] == 0


def test_ray_backend_runs_real_episodes_and_resumes(tmp_path):
    """The same bench on a local Ray instance (RAY_ADDRESS would name a cluster): records, then a resume
    that runs only the new jobs."""
    ray = pytest.importorskip("ray")
    from driveopt.experiments.bench import episode_record

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        spec = BenchSpec(("two-lane-d1.0",), ("idm",), (42,), 2, {"duration": 0.3})
        run_bench(spec, tmp_path, backend="ray", episode_fn=episode_record, progress=False)
        first = load_records(tmp_path / "episodes.jsonl")
        assert sorted(r["episode"] for r in first) == [0, 1] and all(r["steps"] >= 1 for r in first)
        more = BenchSpec(spec.scenarios, spec.planners, spec.seeds, 3, spec.options)
        run_bench(more, tmp_path, backend="ray", episode_fn=episode_record, progress=False)
        records = load_records(tmp_path / "episodes.jsonl")
        assert records[:2] == first and sorted(r["episode"] for r in records) == [0, 1, 2]
    finally:
        ray.shutdown()


def test_ray_backend_without_ray_is_a_clear_error(tmp_path, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray":
            raise ImportError("No module named 'ray'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    with pytest.raises(DriveoptError, match=r"driveopt\[ray\]"):
        run_bench(SPEC, tmp_path / "out", backend="ray", episode_fn=fake_episode, progress=False)
    assert not (tmp_path / "out").exists()  # refused before anything was written


@pytest.mark.parametrize("options, match", [
    ({"duration": -3.0}, "duration must be a finite number > 0"),
    ({"duration": float("nan")}, "duration must be a finite number > 0"),
    ({"duration": float("inf")}, "duration must be a finite number > 0"),
    ({"samples": 0}, "samples must be an integer >= 1"),
    ({"weights": "no/such/file.ckpt"}, "weights file no/such/file.ckpt does not exist"),
    ({"weights": __file__}, "none of the planners grid, bilevel takes weights"),  # a file, but no planner reads it
    ({"config": {"cost": {"no_such_weight": 1.0}}}, "no_such_weight"),
])
def test_invalid_options_are_refused_before_anything_is_written(tmp_path, options, match):
    spec = BenchSpec(SPEC.scenarios, SPEC.planners, SPEC.seeds, SPEC.episodes, options)
    with pytest.raises(DriveoptError, match=match):
        run_bench(spec, tmp_path / "out", workers=1, episode_fn=fake_episode, progress=False)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("names, match", [
    ({"scenarios": ("no-such-scenario",)}, "no-such-scenario"),
    ({"planners": ("grid", "no-such-planner")}, "no-such-planner"),
])
def test_unknown_names_are_refused_before_anything_is_written(tmp_path, names, match):
    spec = BenchSpec(**{"scenarios": SPEC.scenarios, "planners": SPEC.planners, **names})
    with pytest.raises(DriveoptError, match=match):
        run_bench(spec, tmp_path / "out", workers=1, episode_fn=fake_episode, progress=False)
    assert not (tmp_path / "out").exists()


def test_a_folder_without_episodes_takes_other_options(tmp_path):
    """spec.json alone (a run stopped before its first episode) does not bind the folder."""
    run_bench(BenchSpec(SPEC.scenarios, SPEC.planners, episodes=0, options={"duration": 5.0}), tmp_path,
              workers=1, episode_fn=fake_episode, progress=False)
    assert json.loads((tmp_path / "spec.json").read_text())["options"] == {"duration": 5.0}
    run_bench(SPEC, tmp_path, workers=1, episode_fn=fake_episode, progress=False)
    assert json.loads((tmp_path / "spec.json").read_text())["options"] == {}
    assert len(load_records(tmp_path / "episodes.jsonl")) == len(SPEC.jobs())


def test_cli_bench_refuses_bad_options_without_writing_then_runs(tmp_path, capsys, monkeypatch):
    """`driveopt bench --duration -3 --out D` is one line and exit 2, and leaves D free for the corrected rerun."""
    import functools

    from driveopt.cli import main
    from driveopt.experiments import bench

    monkeypatch.setattr(bench, "run_bench", functools.partial(bench.run_bench, episode_fn=fake_episode, progress=False))
    out = tmp_path / "D"
    argv = ["bench", "--scenarios", "two-lane-d1.0", "--planners", "idm", "--episodes", "2", "--workers", "1", "--out", str(out)]
    with pytest.raises(SystemExit) as exit_:  # refused by the argument's type, when parsed
        main([*argv, "--duration", "-3"])
    assert exit_.value.code == 2
    assert capsys.readouterr().err == "driveopt: error: argument --duration: duration must be in (0, 3600] s, got -3 (see driveopt bench --help)\n"
    assert not out.exists()
    assert main([*argv, "--episode-list", "2"]) == 2
    assert "episode list [2]" in capsys.readouterr().err and not out.exists()
    assert main([*argv, "--duration", "3", "--episode-list", "1"]) == 0
    assert [r["episode"] for r in load_records(out / "episodes.jsonl")] == [1]
    assert main([*argv, "--duration", "3"]) == 0
    assert len(load_records(out / "episodes.jsonl")) == 2


def test_cli_bench_out_is_a_file(tmp_path, capsys):
    from driveopt.cli import main

    (tmp_path / "X").write_text("not a folder")
    assert main(["bench", "--scenarios", "two-lane-d1.0", "--planners", "idm", "--out", str(tmp_path / "X")]) == 2
    assert capsys.readouterr().err == f"driveopt: error: the output folder {tmp_path / 'X'} is an existing file; give a folder (for episodes.jsonl, spec.json and the summaries)\n"
    assert (tmp_path / "X").read_text() == "not a folder"


def test_scenario_overrides_and_replan_period_are_bench_options(tmp_path):
    from driveopt.experiments.bench import episode_record
    from driveopt.experiments.store import JobKey

    with pytest.raises(DriveoptError, match="traffic_reverses must be true or false"):
        BenchSpec(("two-lane-d1.0",), ("grid",), options={"scenario": {"traffic_reverses": "no"}}).check()
    with pytest.raises(DriveoptError, match="replan_every"):
        BenchSpec(("two-lane-d1.0",), ("grid",), options={"replan_every": 0}).check()
    options = {"duration": 0.5, "replan_every": 5, "scenario": {"traffic_reverses": False}}
    record = episode_record(JobKey("two-lane-d1.0", "grid", 42, 0), options)
    assert record["steps"] == 5 and len(record["plan_ms"]) == 1  # one plan executed for five periods
    assert record["device"] == "cpu"  # the JAX backend it planned on (the test machine has no accelerator)


def test_summarise_merges_bench_folders_and_refuses_duplicates(tmp_path, capsys):
    from driveopt.cli import main

    for planner in ("idm", "bilevel"):
        spec = BenchSpec(scenarios=("four-lane-d3.0",), planners=(planner,), seeds=(42,), episodes=4)
        run_bench(spec, tmp_path / planner, workers=1, episode_fn=fake_episode, progress=False)
    out = tmp_path / "merged"
    assert main(["summarise", str(tmp_path / "idm"), str(tmp_path / "bilevel" / "episodes.jsonl"), "--out", str(out)]) == 0
    table = (out / "summary.md").read_text()
    assert "| four-lane-d3.0 | bilevel | 4 |" in table and "(idm) |" in table and (out / "summary.png").stat().st_size > 0
    capsys.readouterr()
    assert main(["summarise", str(tmp_path / "idm"), str(tmp_path / "idm"), "--out", str(out)]) == 2
    assert "pass each run once" in capsys.readouterr().err
    assert main(["summarise", str(tmp_path / "missing"), "--out", str(out)]) == 2
    (tmp_path / "file").write_text("x")
    capsys.readouterr()
    assert main(["summarise", str(tmp_path / "idm"), "--out", str(tmp_path / "file" / "sub")]) == 2
    assert "cannot create the output folder" in capsys.readouterr().err


def test_bench_refuses_a_planner_without_usable_weights_before_any_episode(tmp_path):
    """No dqn policy ships for 3-lane roads (or the one given is not a policy): refused up front, nothing written."""
    bad = tmp_path / "policy.zip"
    bad.write_bytes(b"not a zip")
    for options in ({}, {"weights": str(bad)}):
        spec = BenchSpec(scenarios=("three-lane-d1.0",), planners=("dqn",), seeds=(42,), episodes=2, options=options)
        with pytest.raises(DriveoptError, match="policy|dqn"):
            run_bench(spec, tmp_path / "out", workers=1, episode_fn=fake_episode, progress=False)
        assert not (tmp_path / "out" / "episodes.jsonl").exists()


def test_resuming_after_the_shipped_weights_changed_is_refused(tmp_path, monkeypatch):
    """A folder records the digest of the learned weights each planner drove with; replacing the shipped weights
    (same options) must not mix two models in one table."""
    from tiny_models import tiny_cvae

    from driveopt.priors import cvae as cvae_prior

    spec = BenchSpec(scenarios=("four-lane-d3.0",), planners=("cvae", "bilevel"), seeds=(42,), episodes=2)
    run_bench(spec, tmp_path / "out", workers=1, episode_fn=fake_episode, progress=False)
    recorded = json.loads((tmp_path / "out" / "spec.json").read_text())["weights"]
    assert list(recorded) == ["cvae/four-lane-d3.0"]  # bilevel's Gaussian prior has no learned weights
    run_bench(spec, tmp_path / "out", workers=1, episode_fn=fake_episode, progress=False)  # same weights: a resume

    other = tiny_cvae(tmp_path / "other.ckpt")
    monkeypatch.setattr(cvae_prior, "shipped_weights", lambda lanes: other)
    more = BenchSpec(spec.scenarios, spec.planners, spec.seeds, episodes=3)
    with pytest.raises(StoreError, match="cvae/four-lane-d3.0 driven with other learned weights"):
        run_bench(more, tmp_path / "out", workers=1, episode_fn=fake_episode, progress=False)
    assert len(load_records(tmp_path / "out" / "episodes.jsonl")) == 4


def test_resuming_after_a_planners_default_configuration_changed_is_refused(tmp_path, monkeypatch):
    """A folder records the digest of each planner's configuration, its defaults included: a default changed since
    (same options) must not mix two planners in one table; a folder written before configurations were named is
    resumed and names them from then on."""
    from driveopt import registry

    spec = BenchSpec(scenarios=("four-lane-d3.0",), planners=("bilevel", "idm"), seeds=(42,), episodes=2)
    run_bench(spec, tmp_path / "out", workers=1, episode_fn=fake_episode, progress=False)
    folder_spec = json.loads((tmp_path / "out" / "spec.json").read_text())
    assert list(folder_spec["configs"]) == ["bilevel"]  # idm plans with no configuration
    (tmp_path / "out" / "spec.json").write_text(json.dumps({k: v for k, v in folder_spec.items() if k != "configs"}))
    run_bench(spec, tmp_path / "out", workers=1, episode_fn=fake_episode, progress=False)  # an older folder: resumed
    assert json.loads((tmp_path / "out" / "spec.json").read_text())["configs"] == folder_spec["configs"]

    built = registry._built  # the registered planners, as if bilevel's default projection had changed since
    changed = built("bilevel").with_overrides(projection={"max_iterations": 13})
    monkeypatch.setattr(registry, "_built", lambda name: changed if name == "bilevel" else built(name))
    more = BenchSpec(spec.scenarios, spec.planners, spec.seeds, episodes=3)
    with pytest.raises(StoreError, match="bilevel driven with another planner configuration"):
        run_bench(more, tmp_path / "out", workers=1, episode_fn=fake_episode, progress=False)
    assert len(load_records(tmp_path / "out" / "episodes.jsonl")) == 4


def test_an_episode_list_runs_only_those_episodes_and_a_full_run_adds_the_rest(tmp_path):
    chosen = dataclasses.replace(SPEC, episode_list=(2, 0))
    rows = run_bench(chosen, tmp_path, workers=1, episode_fn=fake_episode, progress=False)
    assert sorted({r["episode"] for r in load_records(tmp_path / "episodes.jsonl")}) == [0, 2]
    assert sum(r["episodes"] for r in rows) == 2 * 2 * 2 * 2  # scenarios x planners x seeds x chosen episodes
    run_bench(SPEC, tmp_path, workers=1, episode_fn=fake_episode, progress=False)
    keys = [key_of(r) for r in load_records(tmp_path / "episodes.jsonl")]
    assert len(keys) == len(set(keys)) == len(SPEC.jobs())


def test_runs_that_share_a_folder_are_all_named_in_its_spec_and_summaries(tmp_path):
    first = BenchSpec(("two-lane-d1.0",), ("grid",), (42,), 2)
    second = BenchSpec(("four-lane-d3.0", "two-lane-d1.0"), ("bilevel",), (123,), 1, episode_list=(0,))
    run_bench(first, tmp_path, workers=1, episode_fn=fake_episode, progress=False)
    rows = run_bench(second, tmp_path, workers=1, episode_fn=fake_episode, progress=False)
    spec = json.loads((tmp_path / "spec.json").read_text())
    assert (spec["scenarios"], spec["planners"], spec["seeds"]) == (
        ["two-lane-d1.0", "four-lane-d3.0"], ["grid", "bilevel"], [42, 123])
    assert (spec["episodes"], spec["episode_list"]) == (2, [])  # the first run asked for every episode
    # The second run's rows first, then the first's; every episode of the folder counted once.
    expected = [["four-lane-d3.0", "bilevel", 1], ["two-lane-d1.0", "bilevel", 1], ["two-lane-d1.0", "grid", 2]]
    assert [[r["scenario"], r["planner"], r["episodes"]] for r in rows] == expected
    written = json.loads((tmp_path / "summary.json").read_text())
    assert [[r["scenario"], r["planner"], r["episodes"]] for r in written] == expected


@pytest.mark.parametrize("episode_list", [(3,), (-1,), (1, 1)])
def test_an_episode_list_outside_the_episodes_or_with_repeats_is_refused(tmp_path, episode_list):
    with pytest.raises(BenchOptionError, match="episode list"):
        run_bench(dataclasses.replace(SPEC, episode_list=episode_list), tmp_path / "out", workers=1,
                  episode_fn=fake_episode, progress=False)
    assert not (tmp_path / "out").exists()


# --- one writer per folder, records checked when read -----------------------------------------------------------

TINY_ARGV = ["bench", "--scenarios", "two-lane-d1.0", "--planners", "idm", "--workers", "1"]


def _cli_bench_with_fake_episodes(monkeypatch, episode_fn=fake_episode):
    """`driveopt bench` through the CLI, its episodes ``episode_fn`` (no simulator)."""
    import functools

    from driveopt.experiments import bench

    monkeypatch.setattr(bench, "run_bench", functools.partial(bench.run_bench, episode_fn=episode_fn, progress=False))


def _one_line_error(capsys, argv) -> str:
    from driveopt.cli import main

    try:
        status = main(argv)
    except SystemExit as exc:  # a value an argument's type refuses: the parser exits
        status = exc.code
    assert status == 2
    err = capsys.readouterr().err
    assert err.startswith("driveopt: error: ") and err.count("\n") == 1 and "Traceback" not in err
    return err


def test_a_second_bench_on_a_folder_in_use_is_refused_and_the_first_counts_each_episode_once(tmp_path, capsys, monkeypatch):
    """Two runs on one --out both ran every job before (15 records for 8 jobs); the second is now refused at once."""
    from driveopt.cli import main

    out = tmp_path / "out"
    argv = [*TINY_ARGV, "--episodes", "4", "--out", str(out)]
    second: dict[str, str] = {}

    def episode_starting_a_second_run(job, options):
        if job.episode == 1:  # the first run holds the folder and has written one record
            second["err"] = _one_line_error(capsys, argv)
        return fake_episode(job, options)

    _cli_bench_with_fake_episodes(monkeypatch, episode_starting_a_second_run)
    assert main(argv) == 0
    assert second["err"] == (f"driveopt: error: the output folder {out} is in use by another run (PID {os.getpid()}); "
                             "wait for it to end or choose another output\n")
    keys = [key_of(r) for r in load_records(out / "episodes.jsonl")]
    assert len(keys) == len(set(keys)) == 4
    assert [row["episodes"] for row in json.loads((out / "summary.json").read_text())] == [4]
    assert main(argv) == 0  # the lock went with the run: a resume finds every episode done
    assert len(load_records(out / "episodes.jsonl")) == 4


GOOD_LINE = {"schema": 1, "collided": False, "off_road": False, "mean_speed": 9.0, "plan_ms": [], "sim_seconds": 0.1,
             "plan_seconds": 0.0, "scenario": "two-lane-d1.0", "planner": "idm", "seed": 42, "episode": 7}


def _without(name):
    return json.dumps({k: v for k, v in GOOD_LINE.items() if k != name}).encode()


@pytest.mark.parametrize("line, problem", [
    (None, "idm on two-lane-d1.0, seed 42, episode 0 again (first on line 1)"),  # line 1 repeated
    (_without("planner"), "no field 'planner'"),
    (_without("collided"), "no field 'collided'"),
    (json.dumps({**GOOD_LINE, "seed": "x"}).encode(), "'seed' must be an integer >= 0, got 'x'"),
    (json.dumps({**GOOD_LINE, "collided": "no"}).encode(), "'collided' must be true or false"),
    (json.dumps({**GOOD_LINE, "code": 7}).encode(), "'code' must be a string, got 7"),
    (json.dumps({**GOOD_LINE, "mean_speed": float("nan")}).encode(), "corrupted line (not JSON: NaN is not a JSON value)"),
    ("{\"schema\": 1, \"planner\": \"caf\xe9\"}".encode("latin-1"), "corrupted line (not UTF-8 text)"),
    (b"[1, 2]", "not a JSON object"),
])
def test_a_bad_record_is_refused_with_its_file_and_line_by_bench_and_summarise(tmp_path, capsys, monkeypatch, line, problem):
    """A duplicated line gave "5 of 4 episodes"; a record without planner or collided, a non-UTF-8 line or a seed "x"
    gave tracebacks in bench and summarise."""
    out = tmp_path / "out"
    run_bench(BenchSpec(("two-lane-d1.0",), ("idm",), (42,), 2), out, workers=1, episode_fn=fake_episode, progress=False)
    store = out / "episodes.jsonl"
    first = store.read_bytes().split(b"\n")[0]
    store.write_bytes(store.read_bytes() + (first if line is None else line) + b"\n")
    where = f"{store}:3: "
    _cli_bench_with_fake_episodes(monkeypatch)
    assert where + problem in _one_line_error(capsys, [*TINY_ARGV, "--episodes", "2", "--out", str(out)])
    assert where + problem in _one_line_error(capsys, ["summarise", str(out), "--out", str(tmp_path / "merged")])
    with pytest.raises(StoreError, match=re.escape(where)):
        load_records(store)
    assert not (tmp_path / "merged").exists()


def test_records_without_their_spec_are_refused_never_mixed(tmp_path):
    """spec.json deleted, then a rerun with other options: one table mixed two settings."""
    out = tmp_path / "out"
    run_bench(dataclasses.replace(SPEC, options={"duration": 1.0}), out, workers=1, episode_fn=fake_episode, progress=False)
    (out / "spec.json").unlink()
    before = (out / "episodes.jsonl").read_bytes()
    for options in ({"duration": 2.0}, {"duration": 1.0}):  # without the spec nothing tells which ran with what
        with pytest.raises(StoreError, match="spec.json is missing"):
            run_bench(dataclasses.replace(SPEC, options=options, episodes=4), out, workers=1, episode_fn=fake_episode,
                      progress=False)
    assert (out / "episodes.jsonl").read_bytes() == before and not (out / "spec.json").exists()


def test_a_record_of_another_run_s_settings_is_refused(tmp_path):
    """Each record names its settings: a line of a folder run with another duration does not count here."""
    from driveopt.experiments.store import load_folder

    spec = BenchSpec(("two-lane-d1.0",), ("idm",), (42,), 4)
    run_bench(dataclasses.replace(spec, options={"duration": 1.0}, episode_list=(0, 1)), tmp_path / "a", workers=1,
              episode_fn=fake_episode, progress=False)
    run_bench(dataclasses.replace(spec, options={"duration": 2.0}, episode_list=(3,)), tmp_path / "b", workers=1,
              episode_fn=fake_episode, progress=False)
    assert len(load_folder(tmp_path / "a")[1]) == 2
    with open(tmp_path / "a" / "episodes.jsonl", "ab") as f:
        f.write((tmp_path / "b" / "episodes.jsonl").read_bytes())
    with pytest.raises(StoreError, match=re.escape(f"{tmp_path / 'a' / 'episodes.jsonl'}:3: idm on two-lane-d1.0 ran with other settings")):
        load_folder(tmp_path / "a")
    with pytest.raises(StoreError, match="other settings"):
        run_bench(dataclasses.replace(spec, options={"duration": 1.0}), tmp_path / "a", workers=1, episode_fn=fake_episode,
                  progress=False)


@pytest.mark.parametrize("seeds, needle", [
    (["-1"], "argument --seeds: seed must be in [0, 4294967295], got -1"),
    (["200000000000000"], "argument --seeds: seed must be in [0, 4294967295], got 200000000000000"),
    (["42949"], "seed 42949 is out of range"),  # 42949 x 100003 + 1 > 2**32 - 1: JAX's seed would wrap
    (["42", "42"], "seeds [42, 42]: give each once"),
])
def test_bench_seeds_are_checked_before_anything_is_written(tmp_path, capsys, monkeypatch, seeds, needle):
    """--seeds -1 and 2e14 failed only after spec.json was written."""
    _cli_bench_with_fake_episodes(monkeypatch)
    out = tmp_path / "out"
    assert needle in _one_line_error(capsys, [*TINY_ARGV, "--episodes", "2", "--seeds", *seeds, "--out", str(out)])
    assert not out.exists()


def test_summaries_are_strict_json_with_null_for_missing_numbers(tmp_path, capsys):
    """idm never plans: its plan times are missing, NaN in the rows, null in summary.json (bench and summarise)."""
    from driveopt.cli import main

    def strict(text):
        return json.loads(text, parse_constant=lambda name: pytest.fail(f"{name} in JSON output"))

    spec = BenchSpec(("two-lane-d1.0",), ("idm",), (42,), 2)
    rows = run_bench(spec, tmp_path / "idm", workers=1, episode_fn=idle_episode, progress=False)
    assert np.isnan(rows[0]["plan_ms_median"])
    for name in ("summary.json", "spec.json"):
        strict((tmp_path / "idm" / name).read_text())
    assert strict((tmp_path / "idm" / "summary.json").read_text())[0]["plan_ms_median"] is None
    for line in (tmp_path / "idm" / "episodes.jsonl").read_text().splitlines():
        strict(line)
    assert main(["summarise", str(tmp_path / "idm"), "--out", str(tmp_path / "merged")]) == 0
    assert strict((tmp_path / "merged" / "summary.json").read_text())[0]["plan_ms_p95"] is None
    assert "summary.json" in capsys.readouterr().out


def idle_episode(job, options):
    """An episode of a planner that never plans: no plan times."""
    return {**fake_episode(job, options), "plan_ms": []}


# --- records that cannot belong to their folder's runs ------------------------------------------------------------

def _four_episodes(tmp_path):
    """A folder of 4 idm episodes of seed 42 (fake episodes) and the path of its records."""
    out = tmp_path / "out"
    run_bench(BenchSpec(("two-lane-d1.0",), ("idm",), (42,), 4), out, workers=1, episode_fn=fake_episode, progress=False)
    return out, out / "episodes.jsonl"


def _append_line(path, text: str) -> int:
    """Append ``text`` as a line of ``path``; its line number."""
    with open(path, "a", encoding="utf-8") as f:
        f.write(text + "\n")
    return len(path.read_text().splitlines())


def test_a_record_nested_deeper_than_input_files_may_be_is_refused_with_file_and_line(tmp_path, capsys, monkeypatch):
    """A line nested 100 000 deep ended `summarise` and `bench` in a RecursionError traceback."""
    from driveopt.experiments.store import load_folder

    out, records = _four_episodes(tmp_path)
    first = json.loads(records.read_text().splitlines()[0])
    line = _append_line(records, json.dumps({**first, "episode": 3})[:-1] + ', "x": ' + "[" * 100_000 + "]" * 100_000 + "}")
    needle = f"{records}:{line}: corrupted line (nested deeper than 64 levels"
    with pytest.raises(StoreError, match=re.escape(needle)):
        load_folder(out)
    assert needle in _one_line_error(capsys, ["summarise", str(out), "--out", str(tmp_path / "merged")])
    _cli_bench_with_fake_episodes(monkeypatch)
    assert needle in _one_line_error(capsys, [*TINY_ARGV, "--episodes", "4", "--seeds", "42", "--out", str(out)])
    (out / "spec.json").write_text("[" * 100_000 + "]" * 100_000)
    records.write_text(records.read_text().splitlines(keepends=True)[0])
    assert "spec.json is unreadable (nested deeper than 64 levels)" in _one_line_error(
        capsys, ["summarise", str(out), "--out", str(tmp_path / "merged")])


@pytest.mark.parametrize("change, needle", [
    ({"episode": 77}, "is not an episode of the runs"),  # of a 4-episode run
    ({"seed": 10**400 - 1}, "seeds 42, not 999999999999... (400 characters)"),
    ({"seed": 43}, "seeds 42, not 43"),
    ({"planner": "grid"}, "planners idm, not grid"),
])
def test_a_record_outside_its_folder_s_runs_is_refused_with_file_and_line(tmp_path, capsys, change, needle):
    """Episode 77 of a 4-episode run, carrying the folder's settings digest, was counted: the table showed 5 episodes of
    4; so was a seed of 400 digits."""
    from driveopt.experiments.store import load_folder

    out, records = _four_episodes(tmp_path)
    first = json.loads(records.read_text().splitlines()[0])
    line = _append_line(records, json.dumps({**first, **change}))
    with pytest.raises(StoreError, match=re.escape(f"{records}:{line}: ")) as info:
        load_folder(out)
    assert needle in str(info.value) and "belongs to another run" in str(info.value)
    err = _one_line_error(capsys, ["summarise", str(out), "--out", str(tmp_path / "merged")])
    assert f"{records}:{line}: " in err and needle in err


def test_records_of_a_run_that_extended_the_folder_still_count(tmp_path):
    """A folder run with 2 episodes, then an episode list beyond them, then 6 episodes and another seed (as `driveopt
    reproduce` extends its runs): spec.json grows with each run, so every record lies within it."""
    from driveopt.experiments.store import load_folder

    out = tmp_path / "out"
    spec = BenchSpec(("two-lane-d1.0",), ("idm",), (42,), 2)
    for step in (spec, dataclasses.replace(spec, episodes=9, episode_list=(8,)),
                 dataclasses.replace(spec, seeds=(42, 7), episodes=6)):
        run_bench(step, out, workers=1, episode_fn=fake_episode, progress=False)
    folder, records = load_folder(out)
    assert folder["seeds"] == [42, 7] and folder["episodes"] == 9 and folder["episode_list"] == []
    assert sorted((r["seed"], r["episode"]) for r in records) == [(7, e) for e in range(6)] + [(42, e) for e in (*range(6), 8)]


def test_a_results_line_nested_too_deep_is_malformed_not_a_recursion_error(tmp_path):
    """The offline benchmarks' resumable rows (rows_file): a deep row is dropped and redone like a torn one, a deep
    settings line refuses the file; neither overflows the parser's stack."""
    from driveopt.experiments.rows_file import resume_rows, row_line

    class RowsError(DriveoptError):
        pass

    path, deep = tmp_path / "rows.jsonl", "[" * 100_000 + "]" * 100_000
    path.write_text(row_line({"settings": {"k": 1}}) + row_line({"x": 1}) + deep + "\n" + row_line({"x": 2}))
    assert resume_rows(path, {"k": 1}, lambda record: record["x"], RowsError, "test") == [1]
    assert path.read_text() == row_line({"settings": {"k": 1}}) + row_line({"x": 1})
    path.write_text(deep + "\n")
    with pytest.raises(RowsError, match="is not a test results file"):
        resume_rows(path, {"k": 1}, lambda record: record["x"], RowsError, "test")
