"""P1's RL baselines (issue 16): the training env, the five behaviours, DQN/PPO training that resumes,
the dqn/ppo planners in the standard closed loop, corrupt checkpoints and the missing `rl` extra.

Kept fast: 5 neighbours instead of 50 (the simulator's cost grows with their square), 10 s episodes,
a few hundred training steps, tiny PPO rollouts.
"""

import csv
import json
import shutil
import sys
import zipfile

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from driveopt.cli import main
from driveopt.drivers import rl as rl_driver
from driveopt.experiments.rollout import Rollout, run_episode
from driveopt.observation import observation_vector
from driveopt.registry import get_planner
from driveopt.rl import policy as rl_policy
from driveopt.rl.env import (
    ACTIONS,
    FASTER,
    IDLE,
    LANE_LEFT,
    LANE_RIGHT,
    MAX_TARGET_SPEED,
    OBSERVATION_SCALE,
    SLOWER,
    DrivingEnv,
    RewardWeights,
    apply_behaviour,
)
from driveopt.rl.policy import MissingExtraError, PolicyError, read_record
from driveopt.sim.perception import perceive
from driveopt.sim.scenarios import get_scenario

SMALL = get_scenario("two-lane-d1.0").replace(vehicles_count=5, duration=10.0)
FOUR = get_scenario("four-lane-d1.0").replace(vehicles_count=5, duration=10.0)
DQN_FAST = {"learning_starts": 20}
PPO_FAST = {"n_steps": 32, "batch_size": 16, "n_epochs": 2}


def _train(*args, **kwargs):
    from driveopt.training.rl import train_agent

    return train_agent(*args, progress=False, eval_episodes=1, **kwargs)


def _curve(folder):
    with (folder / "curve.csv").open() as f:
        return [int(row["step"]) for row in csv.DictReader(f)]


@pytest.fixture(scope="module")
def dqn_run(tmp_path_factory):
    """A 100-step DQN run (checkpoint every 50 steps) on the small two-lane scenario."""
    pytest.importorskip("stable_baselines3")
    out = tmp_path_factory.mktemp("rl") / "dqn"
    summary = _train("dqn", SMALL, 100, out, eval_every=50, overrides=DQN_FAST)
    return out, summary


def test_training_env_passes_check_env_and_observes_the_planners_vector():
    env = DrivingEnv(SMALL)
    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=3)
    assert env.observation_space.shape == (55,) and env.action_space.n == 5 and obs.dtype == np.float32
    np.testing.assert_allclose(obs, observation_vector(perceive(env.sim, env.scenario).scene) / OBSERVATION_SCALE)
    assert env.scenario.policy_frequency == 1 and info["time"] == 0.0
    obs, reward, terminated, truncated, info = env.step(IDLE)
    assert info["time"] == pytest.approx(1.0)  # one decision per second (P1 Table II)
    assert set(info["reward_terms"]) == {"collision", "speed", "lane_change", "off_road"}
    assert reward == pytest.approx(sum(info["reward_terms"].values()))
    env.close()


def test_same_seed_same_traffic():
    def run(seed):
        env = DrivingEnv(SMALL)
        frames = [env.reset(seed=seed)[0]]
        frames += [env.step(a)[0] for a in (FASTER, LANE_RIGHT, IDLE)]
        env.close()
        return np.stack(frames)

    np.testing.assert_array_equal(run(5), run(5))
    assert not np.array_equal(run(5), run(6))


def test_the_five_behaviours_move_the_set_points():
    env = DrivingEnv(FOUR)
    env.reset(seed=1)
    car = env.car
    lane, speed = car.target_lane_index[2], car.target_speed
    assert speed == pytest.approx(FOUR.ego_speed) and lane == car.lane_index[2]  # set-points start at the car's state
    assert not apply_behaviour(car, FASTER) and car.target_speed == pytest.approx(speed + 5.0)
    assert not apply_behaviour(car, SLOWER) and not apply_behaviour(car, SLOWER) and car.target_speed == pytest.approx(speed - 5.0)
    assert not apply_behaviour(car, IDLE) and car.target_speed == pytest.approx(speed - 5.0) and car.target_lane_index[2] == lane
    if lane == 0:
        assert apply_behaviour(car, LANE_RIGHT) and car.target_lane_index[2] == 1
        lane = 1
    assert apply_behaviour(car, LANE_LEFT) and car.target_lane_index[2] == lane - 1
    assert apply_behaviour(car, LANE_RIGHT) and car.target_lane_index[2] == lane
    for _ in range(10):
        apply_behaviour(car, FASTER)
        apply_behaviour(car, LANE_LEFT)
    assert car.target_speed == MAX_TARGET_SPEED and car.target_lane_index[2] == 0  # bounded by the grid and the road
    assert not apply_behaviour(car, LANE_LEFT)
    for _ in range(10):
        apply_behaviour(car, SLOWER)
    assert car.target_speed == 0.0
    # Through the env: the step reports the set-points and the lane-change term.
    env.reset(seed=1)
    _, reward, _, _, info = env.step(LANE_RIGHT if env.car.target_lane_index[2] < 3 else LANE_LEFT)
    assert info["reward_terms"]["lane_change"] == RewardWeights().lane_change
    _, _, _, _, info = env.step(FASTER)
    assert info["target_speed"] == pytest.approx(FOUR.ego_speed + 5.0) and info["behaviour"] == "FASTER"
    assert ACTIONS == ("LANE_LEFT", "IDLE", "LANE_RIGHT", "FASTER", "SLOWER")
    env.close()


def test_a_collision_ends_the_episode_with_the_collision_term():
    env = DrivingEnv(SMALL)
    env.reset(seed=2)
    other = next(v for v in env.sim.road.vehicles if v is not env.car)
    other.position = env.car.position + np.array([3.0, 0.0])  # overlapping the ego's front
    other.speed = other.target_speed = 0.0
    _, reward, terminated, truncated, info = env.step(IDLE)
    assert info["crashed"] and terminated and not truncated
    assert info["reward_terms"]["collision"] == RewardWeights().collision and reward < 0
    env.close()


class ScriptedPolicy:
    """Stands in for a Stable-Baselines3 model: a fixed behaviour sequence, recording what it saw."""

    def __init__(self, actions):
        self.actions, self.seen = list(actions), []

    def predict(self, obs, deterministic=False):
        self.seen.append(np.array(obs))
        return np.array(self.actions[len(self.seen) - 1]), None


def test_the_driver_drives_the_dynamics_of_the_training_env(monkeypatch):
    """Same seed and behaviours: the 10 Hz closed loop (a decision every 10 steps) and the 1 Hz training env
    see the same observations and move the car the same way."""
    actions = [FASTER, LANE_RIGHT, SLOWER, FASTER]
    env = DrivingEnv(SMALL)
    obs = [env.reset(seed=12)[0]]
    positions = []
    for a in actions:
        obs.append(env.step(a)[0])
        positions.append(env.car.position.copy())
    env.close()
    scripted = ScriptedPolicy(actions)
    monkeypatch.setattr(rl_driver, "cached_policy", lambda *args: scripted)
    driver = get_planner("dqn").with_weights("scripted.zip").driver()
    rollout = Rollout(SMALL, driver, seed=12, duration=len(actions))
    visited = [step.env.unwrapped.vehicle.position.copy() for step in rollout if len(step.episode.speeds) % 10 == 0]
    assert driver.behaviours == [ACTIONS[a] for a in actions]
    np.testing.assert_allclose(np.stack(scripted.seen), np.stack(obs[: len(actions)]), atol=1e-5)
    np.testing.assert_allclose(visited[1:], positions[:-1], atol=1e-6)
    assert not rollout.episode.collided and len(rollout.episode.speeds) == 10 * len(actions)


@pytest.mark.parametrize("name", ["three-lane-d2.0", "two-way", "merge"])
def test_every_behaviour_drives_on_every_road_layout(monkeypatch, name):
    monkeypatch.setattr(rl_driver, "cached_policy", lambda *args: ScriptedPolicy(range(len(ACTIONS))))
    scenario = get_scenario(name).replace(vehicles_count=5) if name.endswith("d2.0") else get_scenario(name)
    driver = get_planner("ppo").with_weights("scripted.zip").driver()
    episode = Rollout(scenario, driver, seed=1, duration=len(ACTIONS)).run()
    assert driver.behaviours == list(ACTIONS)[: len(driver.behaviours)]
    assert len(driver.behaviours) == len(ACTIONS) or episode.collided
    assert np.all(np.isfinite(episode.speeds)) and episode.sim_duration > 0


def test_dqn_trains_resumes_without_repeating_work_and_drives(dqn_run, tmp_path):
    out, first = dqn_run
    assert first["steps"] == 100 and first["train_steps_per_s"] > 0
    assert {"last.zip", "best.zip", "curve.csv", "summary.json", "replay_buffer-100.pkl"} <= {p.name for p in out.iterdir()}
    assert _curve(out) == [50, 100]
    record = read_record(out / "last.zip", "dqn")
    assert record["steps"] == 100 and record["lanes"] == 2 and record["replay_buffer"]["file"] == "replay_buffer-100.pkl"
    assert record["settings"]["gamma"] == 0.8 and record["settings"]["buffer_size"] == 15_000  # P1 Table II
    folder = tmp_path / "dqn"
    shutil.copytree(out, folder)
    with (folder / "curve.csv").open("a") as f:  # a row of work lost after the checkpoint, and a torn one
        f.write("170,1.0,-1.0,0.0,1,9.0,1.0\n100,0.0,2")
    resumed = _train("dqn", SMALL, 160, folder, eval_every=50, overrides=DQN_FAST)
    assert resumed["steps"] == 160 and resumed["steps_this_run"] == 60  # continues at 100, no step repeated
    assert _curve(folder) == [50, 100, 150, 160]
    assert [p.name for p in folder.glob("replay_buffer-*.pkl")] == ["replay_buffer-160.pkl"]
    from driveopt.rl.policy import load_model

    model, _ = load_model(folder / "last.zip", "dqn")
    assert model.num_timesteps == 160 and model.replay_buffer.size() == 0  # the buffer lives beside the zip
    model.load_replay_buffer(str(folder / "replay_buffer-160.pkl"))
    assert model.replay_buffer.size() == 160  # the resumed run continued the first run's buffer
    # The planner drives with it in the standard 10 Hz loop.
    episode = run_episode(SMALL, get_planner("dqn").with_weights(str(folder / "best.zip")), seed=4, duration=2.0)
    assert len(episode.speeds) == 20 and np.all(np.isfinite(episode.speeds))


def test_ppo_trains_resumes_and_drives(tmp_path):
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "ppo"
    assert _train("ppo", SMALL, 64, out, eval_every=32, overrides=PPO_FAST)["steps"] == 64
    resumed = _train("ppo", SMALL, 128, out, eval_every=32, overrides=PPO_FAST)
    assert (resumed["steps"], resumed["steps_this_run"]) == (128, 64)
    assert _curve(out) == [32, 64, 96, 128] and not list(out.glob("replay_buffer-*"))
    assert read_record(out / "best.zip", "ppo")["settings"]["gae_lambda"] == 0.95
    driver = get_planner("ppo").with_weights(str(out / "best.zip")).driver()
    episode = Rollout(SMALL, driver, seed=4, duration=2.0).run()
    assert len(episode.speeds) == 20 and len(driver.behaviours) == 2


def test_corrupt_or_mismatched_checkpoints_are_refused(dqn_run, tmp_path):
    out, _ = dqn_run
    folder = tmp_path / "dqn"
    shutil.copytree(out, folder)
    with pytest.raises(PolicyError, match="holds a 'dqn' checkpoint, expected 'ppo'"):
        _train("ppo", SMALL, 200, folder, eval_every=50)
    with pytest.raises(PolicyError, match="another seed"):
        _train("dqn", SMALL, 200, folder, eval_every=50, seed=1, overrides=DQN_FAST)
    with pytest.raises(PolicyError, match="another scenario"):
        _train("dqn", SMALL.replace(vehicles_count=6), 200, folder, eval_every=50, overrides=DQN_FAST)
    buffer = folder / "replay_buffer-100.pkl"
    buffer.write_bytes(buffer.read_bytes()[:-10])
    with pytest.raises(PolicyError, match="replay_buffer-100.pkl is corrupted"):
        _train("dqn", SMALL, 200, folder, eval_every=50, overrides=DQN_FAST)
    last = folder / "last.zip"
    last.write_bytes(last.read_bytes()[: last.stat().st_size // 2])  # a truncated copy
    with pytest.raises(PolicyError, match="corrupted"):
        _train("dqn", SMALL, 200, folder, eval_every=50, overrides=DQN_FAST)
    with pytest.raises(PolicyError, match="corrupted"):
        run_episode(SMALL, get_planner("dqn").with_weights(str(last)), seed=1, duration=0.3)
    plain = tmp_path / "plain.zip"  # a zip without the driveopt record
    with zipfile.ZipFile(plain, "w") as z:
        z.writestr("data", "{}")
    with pytest.raises(PolicyError, match="not a driveopt policy"):
        run_episode(SMALL, get_planner("ppo").with_weights(str(plain)), seed=1, duration=0.3)
    with pytest.raises(PolicyError, match="holds a 'dqn' policy, expected 'ppo'"):
        run_episode(SMALL, get_planner("ppo").with_weights(str(out / "best.zip")), seed=1, duration=0.3)
    with pytest.raises(PolicyError, match="trained on 2-lane roads; this road has 4 lanes"):
        run_episode(FOUR, get_planner("dqn").with_weights(str(out / "best.zip")), seed=1, duration=0.3)


def test_shipped_policies_are_chosen_by_lane_count(monkeypatch, tmp_path):
    (tmp_path / "weights").mkdir()
    (tmp_path / "weights" / "ppo-two-lane.zip").write_bytes(b"")
    monkeypatch.setattr(rl_policy.resources, "files", lambda package: tmp_path)
    assert get_planner("ppo").policy_file(SMALL) == tmp_path / "weights" / "ppo-two-lane.zip"
    assert get_planner("ppo").with_weights("mine.zip").policy_file(SMALL).name == "mine.zip"
    with pytest.raises(PolicyError, match="no dqn policy shipped for 2-lane roads: train one with "
                                          "`driveopt train dqn --scenario two-lane-d1.0 --steps 5000000"):
        get_planner("dqn").policy_file(SMALL)
    with pytest.raises(PolicyError, match="dqn-four-lane"):
        get_planner("dqn").policy_file(FOUR)


@pytest.mark.parametrize("algo", ["dqn", "ppo"])
@pytest.mark.parametrize("lanes", [2, 4])
def test_shipped_policies_are_what_their_names_say_and_drive(algo, lanes):
    """Each shipped file is a checksummed driveopt policy of its algorithm, trained on a road of its lane
    count with the training env's current reward and settings, and the planner drives with it."""
    pytest.importorskip("stable_baselines3")
    from driveopt.training.rl import settings_for

    path = rl_policy.shipped_policy(algo, lanes)
    assert path is not None and path.name == f"{algo}-{rl_policy.lane_word(lanes)}-lane.zip"
    record = read_record(path, algo)
    assert record["lanes"] == lanes and record["scenario"]["lanes"] == lanes
    assert record["reward_weights"] == RewardWeights().to_dict()
    assert record["settings"] == settings_for(algo, record["envs"])
    assert record["replay_buffer"] is None  # nothing beside the file is needed to drive
    road = SMALL if lanes == 2 else FOUR
    episode = run_episode(road, get_planner(algo), seed=3, duration=3.0)
    assert (len(episode.speeds) == 30 or episode.collided) and len(episode.speeds) >= 1 and np.all(np.isfinite(episode.speeds))


def test_train_command_and_its_errors(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    small = tmp_path / "small.json"
    small.write_text(json.dumps({"vehicles_count": 5, "duration": 5.0}))
    args = ["train", "dqn", "--scenario", "two-lane-d1.0", "--scenario-config", str(small), "--steps", "30",
            "--out", str(tmp_path / "cli"), "--eval-every", "15", "--eval-episodes", "1"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "trained dqn to 30 steps" in printed and "training steps/s" in printed
    summary = json.loads((tmp_path / "cli" / "summary.json").read_text())
    assert summary["train_steps_per_s"] > 0 and summary["steps"] == 30
    assert main(["train", "ppo", *args[2:]]) == 2  # the dqn folder is not a ppo checkpoint
    assert "expected 'ppo'" in capsys.readouterr().err
    assert main(["train", "dqn", "--scenario", "six-lane", "--steps", "5", "--out", str(tmp_path / "x")]) == 2
    assert "valid scenarios" in capsys.readouterr().err
    assert main(["train", "dqn", "--scenario", "two-lane-d1.0", "--steps", "5", "--out", str(tmp_path / "x"), "--device", "gpu"]) == 2
    assert "not a PyTorch device" in capsys.readouterr().err and not (tmp_path / "x").exists()


def test_without_the_rl_extra_one_line_names_the_install(monkeypatch, tmp_path, capsys, dqn_run):
    out, _ = dqn_run
    monkeypatch.setitem(sys.modules, "stable_baselines3", None)  # import stable_baselines3 -> ImportError
    monkeypatch.setattr(rl_policy, "_CACHE", {})
    assert main(["train", "dqn", "--scenario", "two-lane-d1.0", "--steps", "5", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "pip install 'driveopt[rl]'" in err
    assert not (tmp_path / "x").exists()  # nothing written
    with pytest.raises(MissingExtraError, match=r"pip install 'driveopt\[rl\]'"):
        run_episode(SMALL, get_planner("dqn").with_weights(str(out / "best.zip")), seed=1, duration=0.3)
