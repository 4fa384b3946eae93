"""`driveopt train dqn|ppo` writes TensorBoard event files that TensorBoard reads: training scalars and each
evaluation, in one run folder that a resumed run appends to."""

from __future__ import annotations

import json
import zipfile

import pytest

from driveopt.sim.scenarios import get_scenario

SMALL = get_scenario("two-lane-d1.0").replace(vehicles_count=3, duration=5.0)  # 5 steps of 1 s per episode


def _scalars(folder):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(folder))
    events.Reload()
    return {tag: [(e.step, e.value) for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}


def test_train_writes_event_files_that_tensorboard_reads_and_resumes_into_them(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("tensorboard")
    from driveopt.cli import main

    out = tmp_path / "dqn"
    argv = ["train", "dqn", "--scenario", "two-lane-d1.0", "--steps", "30", "--out", str(out), "--eval-every", "15",
            "--eval-episodes", "1"]
    config = tmp_path / "small.json"
    config.write_text(json.dumps({"vehicles_count": SMALL.vehicles_count, "duration": SMALL.duration}))
    argv += ["--scenario-config", str(config)]
    assert main(argv) == 0
    assert f"tensorboard --logdir {out / 'tensorboard'}" in capsys.readouterr().out
    runs = sorted(p.name for p in (out / "tensorboard").iterdir())
    assert runs == ["dqn_1"] and list((out / "tensorboard" / "dqn_1").glob("events.out.tfevents.*"))
    scalars = _scalars(out / "tensorboard" / "dqn_1")
    assert [step for step, _ in scalars["eval/collision_rate"]] == [15, 30]
    assert "rollout/ep_rew_mean" in scalars, "Stable-Baselines3's own training scalars"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["tensorboard"] == str(out / "tensorboard")
    assert summary["last_eval"]["mean_return"] == pytest.approx(scalars["eval/mean_return"][-1][1], rel=1e-5)
    with zipfile.ZipFile(out / "best.zip") as policy:
        assert str(tmp_path) not in policy.read("data").decode(), "no path of this machine in the policy file"
    # resuming to 45 steps appends to the same run folder
    argv[argv.index("30")] = "45"
    assert main(argv) == 0
    assert sorted(p.name for p in (out / "tensorboard").iterdir()) == ["dqn_1"]
    assert [step for step, _ in _scalars(out / "tensorboard" / "dqn_1")["eval/collision_rate"]] == [15, 30, 45]
