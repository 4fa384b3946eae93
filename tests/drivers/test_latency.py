"""A closed loop that pays for planning time: the latency strategies, the driver's delayed plans, and the bench option."""

import json
import math
from types import SimpleNamespace

import pytest

from driveopt.drivers.latency import Fixed, LatencyError, Measured, Synchronous, parse_latency, periods_after
from driveopt.drivers.optimiser import OptimiserSpec
from driveopt.errors import DriveoptError
from driveopt.experiments.rollout import Rollout
from driveopt.registry import get_planner

SCENARIO = "two-lane-d1.0"  # 10 Hz policy
PERIOD = 0.1  # [s]


def _spec(latency=None) -> OptimiserSpec:
    return get_planner("grid").with_samples(20).with_latency(latency)


def _drive(spec: OptimiserSpec, duration: float = 1.0) -> tuple[Rollout, list[dict]]:
    """A 1 s episode of ``spec`` and, for each step, what the driver executed and what took effect."""
    rollout = Rollout(SCENARIO, spec.driver(), seed=3, duration=duration)
    steps = []
    for step in rollout:
        decision = step.decision
        steps.append({"ego_x": float(step.env.unwrapped.vehicle.position[0]), "delivered": decision.result is not None,
                      "periods": decision.latency_periods, "index": decision.plan_index,
                      "elapsed": decision.plan_elapsed, "planned_x": decision.scene.ego.x if decision.scene else None})
    return rollout, steps


@pytest.mark.parametrize("text, expected", [
    (None, Synchronous()), ("sync", Synchronous()), ("measured", Measured()), ("250", Fixed(250.0)), (0, Fixed(0.0)),
    (Fixed(40.0), Fixed(40.0)),
])
def test_latency_spellings(text, expected):
    assert parse_latency(text) == expected


@pytest.mark.parametrize("value", ["-5", -0.1, float("nan"), float("inf"), 10_000.5, "fast", True, [250]])
def test_bad_latencies_are_refused_in_one_line(value):
    with pytest.raises(LatencyError, match="latency must be 'sync', 'measured' or a number of milliseconds"):
        parse_latency(value)


def test_compute_time_is_rounded_up_to_whole_periods_and_at_least_one():
    assert [periods_after(s, PERIOD) for s in (0.0, 0.04, 0.1, 0.2, 0.25, 0.3, 0.7, 0.1001)] == [1, 1, 1, 2, 3, 3, 7, 2]
    assert Fixed(250.0).periods(0.01, PERIOD) == 3 and Measured().periods(0.01, PERIOD) == 1
    assert Synchronous().periods(5.0, PERIOD) == 0


def test_sync_is_the_closed_loop_that_waits_for_every_plan():
    """The default is synchronous; naming it changes nothing: the same episode, every step planned and executed at
    once, and records without plan_periods (a bench folder's records are those made before the option existed)."""
    assert _spec("sync") == _spec() and _spec().latency == Synchronous()
    plain, plain_steps = _drive(_spec())
    named, named_steps = _drive(_spec("sync"))
    assert plain.episode.speeds == named.episode.speeds and len(plain.episode.speeds) == 10
    assert all(s["delivered"] and s["periods"] is None and s["elapsed"] == 0.0 for s in named_steps)
    assert [s["index"] for s in named_steps] == list(range(10))
    assert "plan_periods" not in named.episode.record() and "plan_periods_max" not in named.episode.summary()


def test_a_fixed_latency_delivers_each_plan_periods_after_it_started(monkeypatch):
    """250 ms at 10 Hz: the first plan is waited for; then a plan starts at step 1 and every 3 steps (when the
    previous is delivered) and takes effect 3 steps after it started, made from the state predicted for that step
    (where the car then is) and tracked from its start; meanwhile the car tracks the plan in effect further along."""
    from driveopt.drivers import optimiser

    calls = []
    real_plan = optimiser.plan

    def counting_plan(*args, **kwargs):
        calls.append(kwargs.get("x_offset"))
        return real_plan(*args, **kwargs)

    monkeypatch.setattr(optimiser, "plan", counting_plan)
    rollout, steps = _drive(_spec(250))
    assert len(calls) == 1 + 4  # the warm-up in reset, then plans started at steps 0, 1, 4 and 7
    delivered = [i for i, s in enumerate(steps) if s["delivered"]]
    assert delivered == [0, 4, 7] and [steps[i]["periods"] for i in delivered] == [0, 3, 3]
    assert [s["index"] for s in steps] == [0, 0, 0, 0, 1, 1, 1, 2, 2, 2]
    assert [round(s["elapsed"] / PERIOD) for s in steps] == [0, 1, 2, 3, 0, 1, 2, 0, 1, 2]
    started = [i - steps[i]["periods"] for i in delivered]
    assert started == [0, 1, 4]
    assert all(steps[i]["planned_x"] == pytest.approx(steps[i]["ego_x"], abs=0.05) for i in delivered)
    record = rollout.episode.record()
    assert record["plan_periods"] == [0, 3, 3] and len(record["plan_ms"]) == 3
    assert rollout.episode.summary()["plan_periods_max"] == 3


def test_measured_latency_rounds_the_measured_compute_time_up(monkeypatch):
    """Every call timed at 130 ms (a fake clock): each plan takes effect 2 periods after it started. The first
    real-time call expected one period (it planned from the state a period ahead: tracked from 0.1 s into it when it
    arrives a period later), the others two (tracked from their start)."""
    from driveopt.drivers import optimiser

    clock = SimpleNamespace(now=0.0)

    def perf_counter():
        clock.now += 0.13
        return clock.now

    monkeypatch.setattr(optimiser, "time", SimpleNamespace(perf_counter=perf_counter))
    rollout, steps = _drive(_spec("measured"))
    delivered = [i for i, s in enumerate(steps) if s["delivered"]]
    assert delivered == [0, 3, 5, 7, 9]
    assert rollout.episode.plan_periods == [0, 2, 2, 2, 2]
    assert rollout.episode.plan_ms == pytest.approx([130.0] * 5)
    assert [round(s["elapsed"] / PERIOD) for s in steps] == [0, 1, 2, 1, 2, 0, 1, 0, 1, 0]


def test_latency_and_replan_every_start_a_call_no_sooner_than_every_n_steps():
    """100 ms (1 period) with plans executed for 3 periods: calls start at steps 0, 3, 6, 9, each taking effect a
    period later (planned from the state predicted for then: tracked from its start); the plan in effect is tracked
    on until then."""
    _, steps = _drive(_spec(100).with_replan_every(3))
    delivered = [i for i, s in enumerate(steps) if s["delivered"]]
    assert delivered == [0, 4, 7]
    assert [s["index"] for s in steps] == [0, 0, 0, 0, 1, 1, 1, 2, 2, 2]
    assert [round(s["elapsed"] / PERIOD) for s in steps] == [0, 1, 2, 3, 0, 1, 2, 0, 1, 2]


def test_latency_is_a_bench_option_and_a_folder_refuses_mixing(tmp_path, capsys, monkeypatch):
    """`bench --latency 250` records the latency in the folder's options (hence in every record's settings); a rerun
    with another latency, synchronous included, is refused; `--latency sync` records nothing, as before."""
    import functools

    from driveopt.cli import main
    from driveopt.experiments import bench
    from driveopt.experiments.store import load_records

    seen = []

    def fake_episode(job, options):
        seen.append(options.get("latency"))
        return {"collided": False, "off_road": False, "mean_speed": 10.0, "plan_ms": [1.0], "sim_seconds": 0.1,
                "plan_seconds": 0.1, "steps": 1}

    monkeypatch.setattr(bench, "run_bench", functools.partial(bench.run_bench, episode_fn=fake_episode, progress=False))
    argv = ["bench", "--scenarios", SCENARIO, "--planners", "idm", "--episodes", "2", "--workers", "1"]
    assert main([*argv, "--out", str(tmp_path / "sync"), "--latency", "sync"]) == 0
    assert main([*argv, "--out", str(tmp_path / "rt"), "--latency", "250"]) == 0
    assert seen == [None, None, 250.0, 250.0]
    assert json.loads((tmp_path / "sync" / "spec.json").read_text())["options"] == {}
    assert json.loads((tmp_path / "rt" / "spec.json").read_text())["options"] == {"latency": 250.0}
    sync_settings = {r["settings"] for r in load_records(tmp_path / "sync" / "episodes.jsonl")}
    rt_settings = {r["settings"] for r in load_records(tmp_path / "rt" / "episodes.jsonl")}
    assert len(sync_settings) == len(rt_settings) == 1 and sync_settings != rt_settings
    for latency in ("measured", "sync"):
        assert main([*argv, "--out", str(tmp_path / "rt"), "--latency", latency]) == 2
        assert "use another output folder" in capsys.readouterr().err
    assert bench.planner_spec("grid", {"latency": 250.0}).latency == Fixed(250.0)
    assert bench.planner_spec("idm", {"latency": "measured"}) == get_planner("idm")
    for bad in ("sync", "250", -1.0, math.nan):
        with pytest.raises(DriveoptError, match="latency"):
            bench.BenchSpec((SCENARIO,), ("grid",), options={"latency": bad}).check()


def test_cli_latency_is_checked_when_parsed(capsys):
    from driveopt.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["drive", "--latency", "-5"])
    assert exit_.value.code == 2
    assert capsys.readouterr().err.startswith("driveopt: error: argument --latency: latency must be 'sync', 'measured'")


def test_the_controller_takes_a_latency():
    from driveopt import Controller

    assert Controller("grid", latency=250).spec.latency == Fixed(250.0)
    assert Controller("grid").spec.latency == Synchronous()
    with pytest.raises(LatencyError):
        Controller("grid", latency="soon")
