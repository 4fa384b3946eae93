"""``driveopt train dqn|ppo``: P1's RL baselines with Stable-Baselines3, resumable.

Settings (:data:`SETTINGS`): P1 Table II where it gives one, else highway-env's own Stable-Baselines3
scripts (which Table II's values match): MLPs with two hidden layers of 256, discount 0.8, learning
rate 5e-4; DQN: replay memory 15k, batch 32, target network updated every 50 steps, exploration from
1 to 0.1 (over the first 70% of the steps; learning starts after 200 steps, one gradient step per env
step); PPO: minibatch 64, GAE lambda 0.95, clip 0.2, value-function coefficient 0.5, 10 epochs per
rollout (Table II's "number of steps 10": with 10 collected steps a minibatch of 64 could not be
drawn, so it is read as the epochs), rollouts of 768 steps over all envs (highway-env's
``batch_size * 12``). ``overrides`` changes any of them (tests use tiny rollouts).

Envs: ``envs`` copies of :class:`driveopt.rl.env.DrivingEnv` (one ``DummyVecEnv`` in this process for
1, else a ``SubprocVecEnv`` of worker processes), env ``i`` seeded ``seed + i`` at its first reset.
PyTorch runs on one thread (``torch.set_num_threads(1)``): the networks are small and the cores are
the envs'.

Output folder:

- ``last.zip``: the checkpoint (a policy file, :mod:`driveopt.rl.policy`, recording the step count,
  scenario, settings and last evaluation); for DQN with ``replay_buffer-<step>.pkl`` beside it (named,
  with its SHA-256, in the record; written before the zip, older ones removed after it);
- ``best.zip``: the policy of the best evaluation so far (fewest collisions, then highest return):
  the one to ship (``src/driveopt/weights/{algo}-{two|four}-lane.zip``) or to pass as ``--weights``;
- ``curve.csv``: one row per evaluation (step, collision rate, mean return, mean speed, wall time,
  steps/s), appended as training goes;
- ``summary.json``: steps, the run's training steps per second, last and best evaluation, the TensorBoard folder;
- ``tensorboard/{algo}_1/``: TensorBoard event files (``tensorboard --logdir OUT/tensorboard``): Stable-Baselines3's
  training scalars (``rollout/ep_rew_mean``, ``train/loss``, ...) and each evaluation's row under ``eval/``, against
  env steps; a resumed run appends to the same run folder. Written with the ``tensorboard`` package (in the ``rl``
  extra); without it, training runs and says once that it writes no TensorBoard logs.

Every ``eval_every`` steps (at the next rollout boundary, where the parameters and the step count
agree) the policy drives ``eval_episodes`` episodes with the fixed seeds ``EVAL_SEED + k``
(deterministic actions) and the checkpoint is written. Rerunning the same command resumes from
``last.zip``: the step count (and DQN's exploration schedule, target-update phase and replay buffer)
continue where the checkpoint was made, so only the steps since the last checkpoint are redone, and
``curve.csv`` keeps exactly the rows up to it. A checkpoint of another algorithm, scenario, seed,
env count or settings is refused (:class:`~driveopt.rl.policy.PolicyError`), as is a corrupted one.
"""

from __future__ import annotations

import csv
import functools
import io
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from driveopt.errors import DriveoptError
from driveopt.files import atomic_write, check_writable_folder, make_output_folder
from driveopt.rl.env import DrivingEnv, RewardWeights, policy_scenario
from driveopt.rl.policy import (
    ALGORITHMS,
    PolicyError,
    algorithm_class,
    buffer_sha256,
    check_algo,
    load_model,
    policy_bytes,
    read_record,
    require_rl,
)
from driveopt.sim.scenarios import Scenario, get_scenario

EVAL_SEED = 1_000_000  # evaluation episode k uses seed EVAL_SEED + k (training envs use seed + i)
PPO_ROLLOUT = 64 * 12  # [steps] per PPO rollout over all envs (highway-env's script: batch_size * 12)
SETTINGS: dict[str, dict[str, Any]] = {
    "dqn": {
        "net_arch": [256, 256],
        "learning_rate": 5e-4,
        "gamma": 0.8,
        "buffer_size": 15_000,
        "batch_size": 32,
        "target_update_interval": 50,
        "exploration_initial_eps": 1.0,
        "exploration_final_eps": 0.1,
        "exploration_fraction": 0.7,
        "learning_starts": 200,
        "train_freq": 1,
        "gradient_steps": 1,
    },
    "ppo": {
        "net_arch": [256, 256],  # policy and value networks each
        "learning_rate": 5e-4,
        "gamma": 0.8,
        "batch_size": 64,
        "gae_lambda": 0.95,
        "clip_range": 0.2,
        "vf_coef": 0.5,
        "n_epochs": 10,
        "n_steps": None,  # [steps per env] None: PPO_ROLLOUT // envs
    },
}
TENSORBOARD_DIR = "tensorboard"  # OUT/tensorboard/{algo}_1: the run's TensorBoard event files
CURVE_FIELDS = ("step", "collision_rate", "mean_return", "mean_speed", "episodes", "wall_s", "train_steps_per_s")


class TrainingError(DriveoptError):
    """Bad training settings (algorithm, step counts, output folder)."""


def settings_for(algo: str, envs: int, overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """The hyperparameters of ``algo`` with ``overrides``; TrainingError naming an unknown key."""
    settings = dict(SETTINGS[algo])
    unknown = sorted(set(overrides or {}) - set(settings))
    if unknown:
        raise TrainingError(f"unknown {algo} setting(s) {unknown}; valid: {sorted(settings)}")
    settings.update(overrides or {})
    if algo == "ppo" and settings["n_steps"] is None:
        settings["n_steps"] = max(PPO_ROLLOUT // envs, 1)
    return settings


def _model_kwargs(algo: str, settings: dict[str, Any]) -> dict[str, Any]:
    kwargs = {k: v for k, v in settings.items() if k != "net_arch"}
    arch = list(settings["net_arch"])
    kwargs["policy_kwargs"] = {"net_arch": arch if algo == "dqn" else {"pi": arch, "vf": arch}}
    return kwargs


def _vec_env(scenario: Scenario, envs: int) -> Any:
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    make = functools.partial(_monitored_env, scenario)
    if envs == 1:
        return DummyVecEnv([make])
    return SubprocVecEnv([make] * envs)  # forkserver (or spawn): workers do not inherit this process's JAX threads


def _monitored_env(scenario: Scenario) -> Any:
    from stable_baselines3.common.monitor import Monitor

    return Monitor(DrivingEnv(scenario))


def evaluate(model: Any, scenario: Scenario, episodes: int) -> dict[str, Any]:
    """Collision rate, mean return and mean speed [m/s] of ``model`` (deterministic) over ``episodes`` fixed-seed episodes."""
    env = DrivingEnv(scenario)
    collisions, returns, speeds = 0, [], []
    try:
        for k in range(episodes):
            obs, _ = env.reset(seed=EVAL_SEED + k)
            total, done, info = 0.0, False, {}
            while not done:
                action, _ = model.predict(obs, deterministic=True)
                obs, reward, terminated, truncated, info = env.step(int(action))
                total += reward
                speeds.append(info["speed"])
                done = terminated or truncated
            collisions += bool(info.get("crashed"))
            returns.append(total)
    finally:
        env.close()
    return {"collision_rate": collisions / episodes, "mean_return": float(np.mean(returns)),
            "mean_speed": float(np.mean(speeds)) if speeds else 0.0, "episodes": episodes}


def _better(new: dict[str, Any], best: dict[str, Any] | None) -> bool:
    return best is None or (new["collision_rate"], -new["mean_return"]) < (best["collision_rate"], -best["mean_return"])


def _check_resume(path: Path, algo: str, record: dict[str, Any], stored: dict[str, Any]) -> None:
    """PolicyError unless the checkpoint ``stored`` was made by the same algorithm, scenario, seed, envs and settings."""
    if stored.get("algo") != algo:
        raise PolicyError(f"{path} holds a '{stored.get('algo')}' checkpoint, expected '{algo}': use another --out")
    for key in ("scenario", "seed", "envs", "settings", "reward_weights"):
        if stored.get(key) != record[key]:
            raise PolicyError(f"{path} was trained with another {key} ({json.dumps(stored.get(key))[:200]}); "
                              f"rerun with the same options or use another --out")


def _read_curve(path: Path, up_to: int) -> list[dict[str, str]]:
    if not path.exists():
        return []
    with path.open(newline="") as f:
        return [row for row in csv.DictReader(f) if row.get("step", "").isdigit() and int(row["step"]) <= up_to]


def _curve_text(rows: list[dict[str, Any]]) -> str:
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=CURVE_FIELDS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return text.getvalue()


def train_agent(
    algo: str,
    scenario: Scenario | str,
    steps: int,
    out: str | Path,
    *,
    envs: int = 1,
    eval_every: int = 10_000,
    eval_episodes: int = 5,
    seed: int = 0,
    device: str = "cpu",
    overrides: dict[str, Any] | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Train ``algo`` (``"dqn"`` or ``"ppo"``) on ``scenario`` to ``steps`` env steps into ``out`` (resuming
    from ``out/last.zip``); returns the summary written to ``out/summary.json``. See the module docstring."""
    if algo not in ALGORITHMS:
        raise TrainingError(f"unknown RL algorithm {algo!r}; valid: {', '.join(ALGORITHMS)}")
    for name, value in (("steps", steps), ("envs", envs), ("eval_every", eval_every), ("eval_episodes", eval_episodes)):
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            raise TrainingError(f"{name} must be an integer >= 1, got {value!r}")
    scenario = policy_scenario(get_scenario(scenario) if isinstance(scenario, str) else scenario)
    settings = settings_for(check_algo(algo), envs, overrides)
    require_rl()
    out = Path(out)
    import torch

    if device != "auto":
        try:
            torch.device(device)
        except RuntimeError as exc:
            raise TrainingError(f"device {device!r} is not a PyTorch device (cpu, cuda, cuda:N, auto): {exc}") from None
    torch.set_num_threads(1)
    check_writable_folder(out, "--out")  # full or read-only: refused now, not at the first checkpoint
    make_output_folder(out, TrainingError, "last.zip, best.zip, curve.csv")
    record = {"algo": algo, "scenario": scenario.to_dict(), "lanes": scenario.lanes, "seed": seed, "envs": envs,
              "settings": settings, "reward_weights": RewardWeights().to_dict()}
    last, curve_path = out / "last.zip", out / "curve.csv"

    stored = read_record(last) if last.exists() else None
    if stored is not None:
        _check_resume(last, algo, record, stored)
    tensorboard_log = tensorboard_folder(out, progress)
    vec = _vec_env(scenario, envs)
    try:
        if stored is None:
            model = algorithm_class(algo)("MlpPolicy", vec, seed=seed, device=device, verbose=0, tensorboard_log=tensorboard_log,
                                          **_model_kwargs(algo, settings))
            done, stored = 0, {}
            atomic_write(curve_path, _curve_text([]).encode())
        else:
            model, stored = load_model(last, algo, env=vec, device=device)
            model.tensorboard_log = tensorboard_log
            done = int(stored["steps"])
            if algo == "dqn":
                _load_buffer(model, out, stored, last)
            model.set_random_seed(seed + done)  # the resumed envs start new episodes, not the first ones again
            # The rows before the checkpoint, then its own evaluation from the checkpoint (the row after it may be
            # missing or torn when the run stopped while appending it); rows of lost steps after it are dropped.
            rows = [r for r in _read_curve(curve_path, done) if int(r["step"]) < done]
            rows += [stored["eval"]] if stored.get("eval") else []
            atomic_write(curve_path, _curve_text(rows).encode())
        summary = _learn(model, algo, scenario, steps, out, record, stored, eval_every, eval_episodes, progress)
    finally:
        vec.close()
    return summary


def tensorboard_folder(out: Path, say: bool = True) -> str | None:
    """``out/tensorboard`` where the ``tensorboard`` package (which Stable-Baselines3 writes event files with) is
    installed, else None (and, with ``say``, one line on stderr naming the package)."""
    import importlib.util

    if importlib.util.find_spec("tensorboard") is None:
        if say:
            print("driveopt: no TensorBoard logs: the tensorboard package is missing (pip install 'driveopt[rl]')",
                  file=sys.stderr)
        return None
    return str(out / TENSORBOARD_DIR)


def _load_buffer(model: Any, out: Path, stored: dict[str, Any], last: Path) -> None:
    entry = stored.get("replay_buffer")
    if not entry:
        return
    path = out / entry["file"]
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise PolicyError(f"{last} needs its replay buffer {path}: {exc.strerror or exc}") from None
    if buffer_sha256(data) != entry.get("sha256"):
        raise PolicyError(f"{path} is corrupted (checksum mismatch: truncated or modified); {last} needs it to resume")
    try:
        model.load_replay_buffer(io.BytesIO(data))
    except Exception as exc:  # unpickling raises many types on a bad file
        raise PolicyError(f"{path} cannot be loaded as a replay buffer: {exc}") from None


def _log_evaluation(model: Any, row: dict[str, Any]) -> None:
    """An evaluation's row in the model's logger (TensorBoard: ``eval/collision_rate``, ...) at its step, written now;
    nothing before ``learn`` has set the logger up."""
    logger = getattr(model, "_logger", None)
    if logger is None:
        return
    for key in ("collision_rate", "mean_return", "mean_speed"):
        logger.record(f"eval/{key}", row[key])
    logger.dump(step=row["step"])


def _learn(model: Any, algo: str, scenario: Scenario, steps: int, out: Path, record: dict[str, Any], stored: dict[str, Any],
           eval_every: int, eval_episodes: int, progress: bool) -> dict[str, Any]:
    """Train from the checkpoint ``stored`` (``{}``: from scratch) to ``steps``; the summary."""
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm import tqdm

    done = int(stored.get("steps", 0))
    start_steps, start = done, time.perf_counter()
    state = {"eval_seconds": 0.0, "best": stored.get("best"), "last_eval": stored.get("eval"), "checkpoint_step": done}

    def train_rate() -> float:
        seconds = time.perf_counter() - start - state["eval_seconds"]
        return (model.num_timesteps - start_steps) / seconds if seconds > 0 else 0.0

    def checkpoint() -> None:
        """Evaluate, then write the checkpoint (buffer first, then last.zip), best.zip, and the curve row."""
        step = int(model.num_timesteps)
        t0 = time.perf_counter()
        result = evaluate(model, scenario, eval_episodes)
        state["eval_seconds"] += time.perf_counter() - t0
        row = {"step": step, **{k: round(v, 6) if isinstance(v, float) else v for k, v in result.items()},
               "wall_s": round(time.perf_counter() - start, 3), "train_steps_per_s": round(train_rate(), 3)}
        _log_evaluation(model, row)
        improved = _better(result, state["best"])
        if improved:
            state["best"] = {**row}
        meta = {**record, "steps": step, "eval": row, "best": state["best"], "replay_buffer": None}
        buffers = sorted(out.glob("replay_buffer-*.pkl"))
        if algo == "dqn":
            data = io.BytesIO()
            model.save_replay_buffer(data)
            name = f"replay_buffer-{step}.pkl"
            atomic_write(out / name, data.getvalue())
            meta["replay_buffer"] = {"file": name, "sha256": buffer_sha256(data.getvalue())}
        blob = policy_bytes(model, meta)
        atomic_write(out / "last.zip", blob)
        for old in buffers:
            if old.name != (meta["replay_buffer"] or {}).get("file"):
                old.unlink(missing_ok=True)
        if improved:  # the policy to drive with: no replay buffer to name
            atomic_write(out / "best.zip", policy_bytes(model, {**meta, "replay_buffer": None}))
        with (out / "curve.csv").open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=CURVE_FIELDS, lineterminator="\n").writerow(row)
        state["last_eval"], state["checkpoint_step"] = row, step
        bar.set_postfix(collisions=f"{row['collision_rate']:.2f}", ret=f"{row['mean_return']:.2f}")

    class Periodic(BaseCallback):
        """Progress bar every step; evaluation and checkpoint at the first rollout start past each eval_every."""

        def __init__(self) -> None:
            super().__init__()
            self.next_eval = (done // eval_every + 1) * eval_every
            self.shown = done

        def _on_rollout_start(self) -> None:
            if self.num_timesteps >= self.next_eval:
                checkpoint()
                self.next_eval = (self.num_timesteps // eval_every + 1) * eval_every

        def _on_step(self) -> bool:
            bar.update(self.num_timesteps - self.shown)
            self.shown = self.num_timesteps
            return True

    bar = tqdm(total=steps, initial=done, desc=f"train {algo} {scenario.name}", unit="step", disable=not progress)
    with bar:
        try:
            if done < steps:
                model.learn(total_timesteps=steps - done, reset_num_timesteps=done == 0, callback=Periodic(), tb_log_name=algo)
        except KeyboardInterrupt:
            step = state["checkpoint_step"]
            kept = f"the checkpoint of step {step} in {out / 'last.zip'}" if step else "no checkpoint yet"
            raise KeyboardInterrupt(f"kept {kept}; rerun the same command to resume") from None
        if state["checkpoint_step"] != model.num_timesteps or not (out / "last.zip").exists():
            checkpoint()
    rate = train_rate()
    summary = {"algo": algo, "scenario": scenario.name, "steps": int(model.num_timesteps),
               "steps_this_run": int(model.num_timesteps - start_steps),
               "seconds": round(time.perf_counter() - start, 3), "eval_seconds": round(state["eval_seconds"], 3),
               "train_steps_per_s": round(rate, 3) if math.isfinite(rate) else None, "envs": record["envs"],
               "last_eval": state["last_eval"], "best": state["best"], "settings": record["settings"],
               "policy": str(out / "best.zip"), "checkpoint": str(out / "last.zip"),
               "tensorboard": model.tensorboard_log}
    atomic_write(out / "summary.json", json.dumps(summary, indent=1).encode())
    return summary
