"""``driveopt bench --lockstep E``: E episodes of an arm stepped together, one planning call per policy step for all.

Tolerance of the closed-loop comparison (the slow test): the same seed gives the same statuses and collisions, and
per-step speeds within 0.5 m/s and lateral positions within 0.2 m of the one-by-one loop. A batched call agrees with
``plan`` to float32 rounding, which the sampler can turn into another pick between near-equal candidates
(tests/core/test_multi_plan.py), and the car then tracks a slightly different plan; over the test's short episodes
the records agree to a few hundredths of a metre per second (measured: mean speeds 8.313 against 8.267 m/s at the
most, 2 s episodes at 20 samples).
"""

import functools

import pytest

from driveopt.drivers.optimiser import OptimiserDriver
from driveopt.experiments.bench import BenchOptionError, BenchSpec, run_bench
from driveopt.experiments.lockstep import LockstepError, cells, run_arm
from driveopt.experiments.rollout import Rollout
from driveopt.experiments.store import JobKey, load_records
from driveopt.registry import get_planner
from driveopt.sim.scenarios import get_scenario

TINY = {"duration": 1.5, "samples": 20, "config": {"sampler": {"num_iterations": 2}, "projection": {"max_iterations": 10}}}


def test_cells_keep_to_one_arm_and_to_slots_times_rounds_jobs():
    jobs = [JobKey(s, p, 42, e) for s in ("a", "b") for e in range(5) for p in ("x", "y")]
    parts = cells(jobs, slots=2, rounds=2)
    assert [len(c) for c in parts] == [4, 1, 4, 1, 4, 1, 4, 1]
    assert all(len({(j.scenario, j.planner) for j in c}) == 1 for c in parts)
    assert sorted(j for c in parts for j in c) == sorted(jobs)


def test_local_workers_each_get_a_share_of_an_arm():
    from driveopt.experiments.bench import lockstep_cells

    jobs = [JobKey("a", "x", 42, e) for e in range(32)]
    assert [len(c) for c in lockstep_cells(jobs, 2, "local", 1)] == [32]  # one process: the arm whole
    assert [len(c) for c in lockstep_cells(jobs, 2, "local", 2)] == [16, 16]
    assert [len(c) for c in lockstep_cells(jobs, 8, "local", 2)] == [16, 16]
    assert [len(c) for c in lockstep_cells(jobs[:20], 2, "local", 2)] == [10, 10]
    assert [len(c) for c in lockstep_cells(jobs, 2, "ray", 1)] == [8, 8, 8, 8]  # CELL_ROUNDS x slots


@pytest.mark.parametrize("planners, options, workers, match", [
    (("idm",), {}, None, "planner idm cannot run in lock-step"),
    (("bilevel", "idm"), {}, None, "planner idm cannot run in lock-step"),
    (("bilevel",), {"latency": "measured"}, None, "latency measured cannot run in lock-step"),
])
def test_lock_step_is_refused_where_it_is_not_valid_before_anything_is_written(tmp_path, planners, options, workers, match):
    spec = BenchSpec(("two-lane-d1.0",), planners, episodes=2, options=options)
    with pytest.raises((LockstepError, BenchOptionError), match=match):
        run_bench(spec, tmp_path / "out", workers=workers, lockstep=2, progress=False)
    assert not (tmp_path / "out").exists()


def test_cli_lockstep_refusal_is_one_line_and_a_nonzero_exit(tmp_path, capsys):
    from driveopt.cli import main

    out = tmp_path / "D"
    code = main(["bench", "--scenarios", "two-lane-d1.0", "--planners", "idm", "--episodes", "1", "--lockstep", "2",
                 "--out", str(out)])
    err = capsys.readouterr().err
    assert code != 0 and err.count("\n") == 1 and "planner idm cannot run in lock-step" in err and not out.exists()
    with pytest.raises(SystemExit) as exit_:
        main(["bench", "--planners", "bilevel", "--lockstep", "0", "--out", str(out)])
    assert exit_.value.code == 2


@pytest.mark.slow  # compiles the planner twice (alone and batched): about two minutes on two busy cores
def test_lock_step_episodes_match_the_one_by_one_loop_and_a_stopped_run_resumes(tmp_path):
    spec = get_planner("bilevel").with_samples(TINY["samples"]).with_overrides(**TINY["config"])
    scenario = get_scenario("four-lane-d3.0").replace(duration=TINY["duration"])
    jobs = [JobKey("four-lane-d3.0", "bilevel", 42, e) for e in range(3)]
    together = {}
    run_arm(jobs, spec, scenario, 2, lambda job, episode: together.__setitem__(job, episode))  # a slot refills
    assert sorted(together) == jobs
    for job in jobs:
        alone = Rollout(scenario, OptimiserDriver(spec), job.env_seed).run()
        lock = together[job]
        assert (lock.statuses, lock.collided, lock.off_road, len(lock.speeds)) == \
            (alone.statuses, alone.collided, alone.off_road, len(alone.speeds))
        assert max(abs(a - b) for a, b in zip(alone.speeds, lock.speeds)) < 0.5
        assert max(abs(a - b) for a, b in zip(alone.lateral, lock.lateral)) < 0.2

    # the bench: stopped after the first record, the rerun adds the rest; records of the one-by-one loop's format
    bench = BenchSpec(("four-lane-d3.0",), ("bilevel",), (42,), 3, TINY)

    class Stop(Exception):
        pass

    from driveopt.experiments import bench as bench_module

    real = bench_module.append_record

    def append_then_stop(path, record):
        real(path, record)
        raise Stop()

    bench_module.append_record = append_then_stop
    try:
        with pytest.raises(Stop):
            run_bench(bench, tmp_path, lockstep=2, progress=False)
    finally:
        bench_module.append_record = real
    assert len(load_records(tmp_path / "episodes.jsonl")) == 1
    run_bench(bench, tmp_path, lockstep=2, progress=False)
    records = load_records(tmp_path / "episodes.jsonl")
    assert sorted(r["episode"] for r in records) == [0, 1, 2] and {r["lockstep"] for r in records} == {2}
    one_by_one = functools.partial(run_bench, bench, tmp_path / "serial", workers=1, progress=False)
    one_by_one()
    serial = {r["episode"]: r for r in load_records(tmp_path / "serial" / "episodes.jsonl")}
    for record in records:
        other = serial[record["episode"]]
        assert set(record) - set(other) == {"lockstep"} and set(other) <= set(record)
        assert (record["statuses"], record["collided"], record["steps"]) == (other["statuses"], other["collided"], other["steps"])
        assert record["mean_speed"] == pytest.approx(other["mean_speed"], abs=0.5)


@pytest.mark.slow  # two worker processes compile the batched planner: about two minutes on two busy cores
def test_local_workers_run_lock_step_cells_and_record_what_one_process_records(tmp_path):
    bench = BenchSpec(("four-lane-d3.0",), ("bilevel",), (42,), 4, {**TINY, "duration": 1.0})
    run_bench(bench, tmp_path / "one", lockstep=2, progress=False)
    run_bench(bench, tmp_path / "two", workers=2, lockstep=2, progress=False)  # cells of CELL_ROUNDS x 2 jobs
    one, two = ({r["episode"]: r for r in load_records(tmp_path / name / "episodes.jsonl")} for name in ("one", "two"))
    assert sorted(two) == [0, 1, 2, 3] and {r["lockstep"] for r in two.values()} == {2}
    for episode, record in two.items():
        assert (record["statuses"], record["collided"], record["steps"]) == \
            (one[episode]["statuses"], one[episode]["collided"], one[episode]["steps"])


@pytest.mark.slow  # a local Ray instance and a compilation inside its worker
def test_ray_runs_lock_step_cells_and_the_parent_writes_their_records(tmp_path):
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        bench = BenchSpec(("four-lane-d3.0",), ("bilevel",), (42,), 3, {**TINY, "duration": 0.5})
        run_bench(bench, tmp_path, backend="ray", lockstep=2, progress=False)
        records = load_records(tmp_path / "episodes.jsonl")
        assert sorted(r["episode"] for r in records) == [0, 1, 2] and {r["lockstep"] for r in records} == {2}
        assert all(r["steps"] == 5 for r in records)
    finally:
        ray.shutdown()
