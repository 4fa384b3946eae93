"""benchmarks/studies/faithful_ablation.py: each variant gives one piece of driveopt's machinery back to a faithful planner,
episodes are written as they end and a rerun resumes; bad input is refused."""

from __future__ import annotations

import json

import pytest

import math

import numpy as np

from driveopt.drivers.commands import EXACT_TRACKING, P2_AUTHORS_COMMAND
from driveopt.ranking import CostPlusResidual, FeasibilityFirst
from driveopt.sim import get_scenario
from driveopt.sim.env import make_env

from benchmarks.studies import faithful_ablation as ablation


def test_each_variant_changes_only_its_piece():
    faithful = ablation.variant_spec("vqvae-faithful", "faithful", 100)
    assert not faithful.method.fallback.in_batch and faithful.loop.executes_infeasible
    assert isinstance(faithful.method.ranking, CostPlusResidual) and not faithful.loop.contact_guard
    net = ablation.variant_spec("vqvae-faithful", "stop-net", 100)
    assert net.method.fallback.in_batch and not net.loop.executes_infeasible and net.method.fallback.evasion
    assert net.method.ranking == faithful.method.ranking and net.config == faithful.config
    ranked = ablation.variant_spec("vqvae-faithful", "feasibility-first", 100)
    assert isinstance(ranked.method.ranking, FeasibilityFirst) and ranked.loop.executes_infeasible
    assert ablation.variant_spec("vqvae-faithful", "contact-guard", 100).loop.contact_guard
    predicted = ablation.variant_spec("vqvae-faithful", "prediction", 100)
    assert predicted.loop.braking_prediction and predicted.loop.approach_selection and not faithful.loop.braking_prediction

    shrestha = ablation.variant_spec("cvae-multipliers-faithful", "faithful", 100)  # [5]'s: driveopt's command
    commanded = ablation.variant_spec("cvae-multipliers-faithful", "authors-command", 100)
    assert commanded.loop.command is P2_AUTHORS_COMMAND and shrestha.loop.command is EXACT_TRACKING
    assert commanded.config == shrestha.config and commanded.loop.measured_start
    started = ablation.variant_spec("cvae-multipliers-faithful", "authors-start", 100)
    assert not started.loop.measured_start and started.config.qp.initial_lateral_acceleration
    assert not shrestha.config.qp.initial_lateral_acceleration
    assert faithful.loop.command is P2_AUTHORS_COMMAND  # P2's pipelines carry their authors' command already
    assert ablation.definition("vqvae-faithful", "faithful", 100) == ablation.definition("vqvae-faithful", "faithful", 100)
    assert ablation.definition("vqvae-faithful", "faithful", 100) != ablation.definition("vqvae-faithful", "stop-net", 100)
    everything = ablation.VARIANTS["authors"]
    assert everything.cars and everything.ego_kinematics and everything.scenario == ablation.AUTHORS_TIMING


def test_the_authors_cars_are_resized_and_their_ego_turns_without_slip():
    class Recorder:
        name = "recorder"

        def reset(self, env, scenario, seed):
            self.sizes = {(v.LENGTH, v.WIDTH, v.diagonal) for v in env.unwrapped.road.vehicles}

    recorder = Recorder()
    env = make_env(get_scenario("two-lane-d1.0"))
    try:
        env.reset(seed=3)
        ablation.WithAuthorsCars(recorder, ego_kinematics=True).reset(env, None, 3)
        assert recorder.sizes == {(4.0, 1.4, math.hypot(4.0, 1.4))}
        ego = env.unwrapped.vehicle
        assert isinstance(ego, ablation.AuthorsEgo)
        ego.speed, ego.heading, start = 10.0, 0.0, ego.position.copy()
        ego.act({"acceleration": 1.0, "steering": 0.1})
        ego.step(0.01)
        assert ego.heading == pytest.approx(10.0 * math.tan(0.1) / 2.0 * 0.01)  # L / 2 = 2 m
        assert np.allclose(ego.position - start, [0.1, 0.0]) and ego.speed == pytest.approx(10.01)
    finally:
        env.close()


def test_episodes_are_written_and_a_rerun_resumes(tmp_path, capsys):
    out = tmp_path / "ablation.jsonl"
    argv = ["--planner", "bilevel-faithful", "--scenario", "two-lane-d1.0", "--seeds", "42", "--episodes", "1",
            "--variants", "faithful", "stop-net", "--samples", "10", "--workers", "1", "--duration", "0.5",
            "--out", str(out)]
    assert ablation.main(argv) == 0
    records = [json.loads(line) for line in out.read_text().splitlines()]
    assert sorted(r["variant"] for r in records) == ["faithful", "stop-net"]
    assert all(r["end_s"] == pytest.approx(0.5, abs=0.11) and r["duration"] == 0.5 for r in records)
    summary = json.loads(out.with_suffix(".summary.json").read_text())["variants"]
    assert summary["faithful"]["episodes"] == 1 and summary["stop-net"]["collisions"] == 0
    capsys.readouterr()
    assert ablation.main(argv) == 0
    assert capsys.readouterr().out.startswith("0 episodes to run (2 in")
    assert len(out.read_text().splitlines()) == 2


@pytest.mark.parametrize("argv", [["--planner", "bilevel"], ["--planner", "bilevel-faithful", "--scenario", "nowhere"],
                                  ["--planner", "bilevel-faithful", "--duration", "0"],
                                  ["--planner", "bilevel-faithful", "--pairs", "42"],
                                  ["--planner", "bilevel-faithful", "--pairs", "42:-1"],
                                  ["--planner", "bilevel-faithful", "--pairs", "a:b"]])
def test_bad_input_is_refused(tmp_path, capsys, argv):
    argv = argv + (["--scenario", "two-lane-d1.0"] if "--scenario" not in argv else []) + ["--out", str(tmp_path / "x")]
    with pytest.raises(SystemExit) as stop:
        ablation.main(argv)
    assert stop.value.code == 2 and "faithful_ablation.py: error:" in capsys.readouterr().err
