"""The training harness: settings and their record, batching, the split, and the resumable epoch loop (resumption
gives the files of an uninterrupted run; other data, settings or configurations are refused; the best epoch is kept;
a diverged loss stops).

The loop is driven by a toy trainer that fits the mean of some points with numpy (nothing to compile), so these tests
take seconds; the trainers' own tests (test_cvae, test_vqvae, test_filter) train the real networks through it."""

from __future__ import annotations

import dataclasses
import json
import math
from typing import Any, ClassVar

import jax
import numpy as np
import pytest
from learned_data import file_fixture, write_synthetic
from tiny_models import with_meta

from driveopt.checks import ConfigError
from driveopt.data.demonstrations import DatasetError
from driveopt.files import LOCK_NAME
from driveopt.learned.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from driveopt.training import cvae, harness, vqvae
from driveopt.training import filter as filter_training
from driveopt.training.harness import (
    BaseTrainConfig,
    EpochTrainer,
    TrainingError,
    TrainingRun,
    accumulate,
    check_same_run,
    chunks,
    epoch_steps,
    load_split,
    minibatches,
    run_epochs,
    train_means,
)

POINTS = np.random.default_rng(0).normal([3.0, -1.0], 1.0, (40, 2))  # the toy trainer's training examples
HELD = np.random.default_rng(1).normal([3.0, -1.0], 1.0, (10, 2))  # and its validation examples
CONFIG = {"dimensions": 2}  # the toy "network configuration" its checkpoints record


@dataclasses.dataclass(frozen=True)
class ToyConfig(BaseTrainConfig):
    epochs: int = 4
    batch_size: int = 16
    step_size: float = 0.5  # [-] share of the way to the minibatch mean per step

    OWN_SETTINGS_AFTER: ClassVar[str] = "batch_size"


class MeanEpochs(EpochTrainer):
    """Moves a point towards each minibatch's mean; loss: the mean squared distance [m^2] to the examples."""

    def __init__(self, state: dict[str, Any], tcfg: ToyConfig, fail_in: int | None, losses: dict[int, float]) -> None:
        self.key, self.tcfg = jax.random.PRNGKey(tcfg.seed), tcfg
        self.point, self.steps_taken = np.asarray(state["params"]["point"]), np.asarray(state["opt_state"]["steps"])
        self.batch_size, self.steps = epoch_steps(len(POINTS), tcfg.batch_size)
        self.fail_in, self.losses = fail_in, losses

    def train_epoch(self, epoch, show):
        if epoch == self.fail_in:
            raise KeyboardInterrupt  # the run is stopped during this epoch
        sums = {"loss": 0.0, "distance": 0.0}
        for idx in minibatches(self.epoch_key(epoch), len(POINTS), self.batch_size, self.steps):
            self.point = self.point + self.tcfg.step_size * (POINTS[idx].mean(0) - self.point)
            self.steps_taken = self.steps_taken + 1
            squared = np.sum((POINTS[idx] - self.point) ** 2, -1)
            accumulate(sums, squared.mean(), {"distance": np.sqrt(squared).mean()})
        record = {"epoch": epoch + 1, **train_means(sums, self.steps)}
        record["train_loss"] = self.losses.get(epoch + 1, record["train_loss"])
        record["val_loss"] = self.losses.get(-(epoch + 1), float(np.mean(np.sum((HELD - self.point) ** 2, -1))))
        return record

    def rank(self, record):
        return record["val_loss"]

    def weights_state(self):
        return {"params": {"point": self.point}}

    def training_state(self):
        return {"params": {"point": self.point}, "opt_state": {"steps": self.steps_taken}}

    def describe(self, record):
        return f"val {record['val_loss']:.3f}"


def train_mean(out, tcfg: ToyConfig = ToyConfig(), *, data: dict[str, Any] | None = None, config: dict[str, Any] = CONFIG,
               stop_after: int | None = None, fail_in: int | None = None, losses: dict[int, float] | None = None) -> dict[str, Any]:
    """Train the toy into ``out`` as a trainer does: checked settings and data, resumed from last.ckpt when there."""
    data = data or {"train": "0123456789abcdef", "validation": "fedcba9876543210", "validation_episodes": 1}
    meta = {"config": config, "train_config": tcfg.record(), "data": data, "rows": {"train": len(POINTS), "validation": len(HELD)}}
    run = TrainingRun(out, "toy", "toy.ckpt", meta)

    def check(path, stored):
        check_same_run(path, stored, tcfg, data, {"config": ("toy configuration", config)})

    state = run.resume({"params": {"point": np.zeros(2)}, "opt_state": {"steps": np.zeros((), np.int64)}}, check)
    run_epochs(run, MeanEpochs(state, tcfg, fail_in, losses or {}), tcfg, desc="toy", progress=False, stop_after=stop_after)
    return run.summary(best_val_loss=run.best)


def folder_bytes(out) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in sorted(out.iterdir()) if path.name != LOCK_NAME}


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    out = tmp_path_factory.mktemp("uninterrupted")
    return out, train_mean(out)


data_file = file_fixture(lambda path: write_synthetic(path, episodes=4, rows=8), "demo.h5")


# ------------------------------------------------------------------------------------------- the epoch loop


def test_a_run_resumed_after_stopping_writes_the_files_of_an_uninterrupted_run(uninterrupted, tmp_path):
    out, summary = uninterrupted
    assert sorted(folder_bytes(out)) == ["history.json", "last.ckpt", "toy.ckpt"]
    assert [r["epoch"] for r in summary["history"]] == [1, 2, 3, 4] and summary["weights"] == str(out / "toy.ckpt")
    assert train_mean(tmp_path, stop_after=1)["epochs"] == 1
    assert train_mean(tmp_path, stop_after=2)["epochs"] == 3
    resumed = train_mean(tmp_path)
    assert resumed["history"] == summary["history"] and resumed["best_val_loss"] == summary["best_val_loss"]
    assert folder_bytes(tmp_path) == folder_bytes(out)
    assert train_mean(tmp_path)["epochs"] == 4 and folder_bytes(tmp_path) == folder_bytes(out)  # nothing left to do


def test_an_interruption_inside_an_epoch_loses_only_that_epoch(uninterrupted, tmp_path):
    with pytest.raises(KeyboardInterrupt):
        train_mean(tmp_path, fail_in=2)
    meta, _ = load_checkpoint(tmp_path / "last.ckpt", "toy")
    assert meta["epoch"] == 2 and len(json.loads((tmp_path / "history.json").read_text())) == 2
    train_mean(tmp_path)
    assert folder_bytes(tmp_path) == folder_bytes(uninterrupted[0])


def test_a_longer_run_extends_the_history(uninterrupted, tmp_path):
    for name, content in folder_bytes(uninterrupted[0]).items():
        (tmp_path / name).write_bytes(content)
    longer = train_mean(tmp_path, dataclasses.replace(ToyConfig(), epochs=6))
    assert longer["history"][:4] == uninterrupted[1]["history"] and [r["epoch"] for r in longer["history"][4:]] == [5, 6]


def test_the_weights_file_holds_the_best_ranked_epoch(tmp_path):
    losses = {-1: 5.0, -2: 2.0, -3: 3.0, -4: 2.5}  # validation losses of epochs 1..4
    summary = train_mean(tmp_path, losses=losses)
    meta, _ = load_checkpoint(tmp_path / "toy.ckpt", "toy")
    assert meta["epoch"] == 2 and [r["val_loss"] for r in meta["history"]] == [5.0, 2.0]
    assert summary["best_val_loss"] == 2.0 == load_checkpoint(tmp_path / "last.ckpt", "toy")[0]["best"]


def test_a_diverged_loss_stops_training_before_anything_of_that_epoch_is_written(tmp_path):
    with pytest.raises(TrainingError, match=r"diverged in epoch 2 \(train loss nan\): lower the learning rate \(now 0.001\)"):
        train_mean(tmp_path, losses={2: math.nan})
    assert load_checkpoint(tmp_path / "last.ckpt", "toy")[0]["epoch"] == 1
    with pytest.raises(TrainingError, match="diverged in epoch 1"):
        train_mean(tmp_path / "first", losses={1: math.inf})
    assert not (tmp_path / "first" / "toy.ckpt").exists() and not (tmp_path / "first" / "last.ckpt").exists()


def test_an_optimiser_state_beyond_the_weights_bound_resumes_and_diverged_weights_do_not(tmp_path):
    """Adam's second moment (squared gradients) and step counter grow past the bound on weights in healthy runs."""
    train_mean(tmp_path, stop_after=2)
    meta, state = load_checkpoint(tmp_path / "last.ckpt", "toy")
    save_checkpoint(tmp_path / "last.ckpt", "toy", {**state, "opt_state": {"steps": np.int64(5_000_000)}}, meta)
    assert train_mean(tmp_path)["epochs"] == 4
    meta, state = load_checkpoint(tmp_path / "last.ckpt", "toy")
    save_checkpoint(tmp_path / "last.ckpt", "toy", {**state, "params": {"point": np.array([1e30, 0.0])}}, meta)
    with pytest.raises(CheckpointError, match=r"beyond \+-1e\+06 \(in \['params'\]\['point'\]\)"):
        train_mean(tmp_path)


# ------------------------------------------------------------------------------------------- resumption refused


def test_a_resumed_run_on_other_data_is_refused(data_file, tmp_path):
    split = load_split(data_file, None, ToyConfig(validation_fraction=0.25))
    train_mean(tmp_path, data=split.record(), stop_after=1)
    other = load_split(write_synthetic(tmp_path / "other.h5", episodes=4, rows=8, seed=7), None, ToyConfig(validation_fraction=0.25))
    with pytest.raises(CheckpointError, match="was trained on other demonstrations .*; use a new --out"):
        train_mean(tmp_path, data=other.record())
    held = load_split(data_file, write_synthetic(tmp_path / "held.h5", episodes=1, rows=8, seed=8), ToyConfig())
    with pytest.raises(CheckpointError, match="held out other validation episodes"):
        train_mean(tmp_path, data=held.record())
    older = tmp_path / "older"
    older.mkdir()
    with_meta(tmp_path / "last.ckpt", older / "last.ckpt", lambda meta: meta.update(data=split.data.fingerprint()))
    with pytest.raises(CheckpointError, match="records no validation split"):
        train_mean(older, data=split.record())
    assert train_mean(tmp_path, data=split.record())["epochs"] == 4  # the same data resumes


def test_other_settings_or_configurations_are_refused_and_later_settings_read_as_their_defaults(uninterrupted, tmp_path):
    last = uninterrupted[0] / "last.ckpt"
    with pytest.raises(CheckpointError, match=r"other settings \{'step_size': \(0.5, 0.25\)\} \(stored, now\)"):
        train_mean(uninterrupted[0], ToyConfig(step_size=0.25))
    with pytest.raises(CheckpointError, match=r"another toy configuration \(\{'dimensions': 2\}, now \{'dimensions': 3\}\)"):
        train_mean(uninterrupted[0], config={"dimensions": 3})
    with_meta(last, tmp_path / "last.ckpt", lambda meta: meta["train_config"].pop("step_size"))  # written before step_size
    assert train_mean(tmp_path)["epochs"] == 4
    with pytest.raises(CheckpointError, match=r"other settings \{'step_size': \(0.5, 0.25\)\}"):
        train_mean(tmp_path, ToyConfig(step_size=0.25))


# ------------------------------------------------------------------------------------------- settings


def test_settings_are_checked_naming_the_trainers_field():
    for bad, message in (({"epochs": 0}, "ToyConfig.epochs must be an integer >= 1"),
                         ({"learning_rate": 0.0}, "ToyConfig.learning_rate must be a finite number > 0"),
                         ({"decay_factor": 1.5}, "ToyConfig.decay_factor must be a finite number > 0 and <= 1"),
                         ({"validation_fraction": 1.0}, "ToyConfig.validation_fraction must be a finite number >= 0 and < 1"),
                         ({"crash_margin": math.nan}, "ToyConfig.crash_margin must be a finite number >= 0 s"),
                         ({"seed": True}, "ToyConfig.seed must be an integer >= 0")):
        with pytest.raises(ConfigError, match=message):
            ToyConfig(**bad)
    with pytest.raises(ConfigError, match="TrainConfig.anneal_epochs must be an integer >= 0"):
        cvae.TrainConfig(anneal_epochs=-1)
    with pytest.raises(ConfigError, match="TrainConfig.reseed_dead_codes must be true or false"):
        vqvae.TrainConfig(reseed_dead_codes=1)
    with pytest.raises(ConfigError, match="TrainConfig.samples_from must be one of vqvae, cvae, gaussian"):
        filter_training.TrainConfig(samples_from="idm")


def test_checkpoints_list_the_settings_in_each_trainers_order():
    common = ["epochs", "batch_size", "learning_rate", "weight_decay", "decay_every", "decay_factor", "validation_fraction",
              "train_episodes", "crash_margin", "seed"]
    assert list(ToyConfig().record()) == [*common[:2], "step_size", *common[2:]]
    assert list(cvae.TrainConfig().record()) == [*common[:6], "beta", "anneal_epochs", *common[6:]]
    assert list(vqvae.TrainConfig().record()) == [*common[:9], "reseed_dead_codes", "seed"]
    filter_own = ["samples", "unroll", "residual_weight", "samples_from"]
    assert list(filter_training.TrainConfig().record()) == [*common[:2], *filter_own, *common[2:]]
    assert filter_training.TrainConfig().record() == dataclasses.asdict(filter_training.TrainConfig())  # the same values, only ordered


# ------------------------------------------------------------------------------------------- batching and split


def test_minibatches_are_whole_batches_of_a_permutation_fixed_by_the_key():
    assert epoch_steps(40, 16) == (16, 2) and epoch_steps(10, 16) == (10, 1)
    key = jax.random.PRNGKey(3)
    batches = minibatches(key, 40, 16, 2)
    assert [len(b) for b in batches] == [16, 16] and len(np.unique(np.concatenate(batches))) == 32
    assert all(np.array_equal(a, b) for a, b in zip(batches, minibatches(key, 40, 16, 2)))
    assert not np.array_equal(batches[0], minibatches(jax.random.PRNGKey(4), 40, 16, 2)[0])


def test_chunks_call_one_shape_and_return_only_the_real_rows():
    shapes = []

    def double(x, y):
        shapes.append(x.shape)
        return {"sum": 2 * x + y}

    parts = chunks([np.arange(10.0), np.ones(10)], double, chunk=4)
    assert shapes == [(4,)] * 3 and [len(p["sum"]) for p in parts] == [4, 4, 2]
    np.testing.assert_array_equal(np.concatenate([p["sum"] for p in parts]), 2 * np.arange(10.0) + 1)


def test_the_split_holds_out_whole_episodes_and_train_episodes_keeps_them(data_file, tmp_path):
    split = load_split(data_file, None, ToyConfig(validation_fraction=0.25))
    assert split.row_counts() == {"train": 24, "validation": 8} and split.held is split.data and split.lanes() == [4]
    held_episodes = set(split.data.episode[split.val_rows])
    assert len(held_episodes) == 1 and not held_episodes & set(split.data.episode[split.train_rows])
    fewer = load_split(data_file, None, ToyConfig(validation_fraction=0.25, train_episodes=2))
    np.testing.assert_array_equal(fewer.val_rows, split.val_rows)
    assert fewer.row_counts()["train"] == 16 and set(fewer.train_rows) < set(split.train_rows)
    with pytest.raises(DatasetError, match="other files than the training ones"):
        load_split(data_file, [data_file], ToyConfig())
    with pytest.raises(DatasetError, match="only 0 usable training rows"):
        load_split(data_file, None, ToyConfig(validation_fraction=0.9))  # every episode held out


def test_an_output_folder_that_is_a_file_is_refused_before_anything_is_read(tmp_path):
    out = tmp_path / "weights.ckpt"
    out.write_text("keep me")
    with pytest.raises(CheckpointError, match="is an existing file; give a folder .*last.ckpt, toy.ckpt, history.json"):
        harness.check_output_folder(out, "toy.ckpt")
    assert out.read_text() == "keep me"


@pytest.mark.parametrize("model", [["cvae"], ["vqvae"], ["filter"], ["cvae-multipliers"]])
@pytest.mark.parametrize("where", ["full disk", "read-only", "under a file"])
def test_train_refuses_an_output_folder_it_cannot_write_before_reading_any_data(tmp_path, capsys, monkeypatch, model,
                                                                                  where):
    """`train cvae` on a full disk failed only after its first epoch (21 s): the folder is now probed first, as the
    other commands probe their outputs."""
    import errno
    import os

    from driveopt import files
    from driveopt.cli import main

    def disk_full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def fail_if_called(*args, **kwargs):
        pytest.fail("the data were read before the output folder was checked")

    out = {"full disk": tmp_path / "new" / "run", "read-only": "/proc/run", "under a file": tmp_path / "f" / "run"}[where]
    reason = {"full disk": "No space left on device", "read-only": "folder /proc", "under a file": "is not a folder"}[where]
    if where == "full disk":
        monkeypatch.setattr(files.os, "fsync", disk_full)
    (tmp_path / "f").write_text("a file")
    monkeypatch.setattr(harness, "load_split", fail_if_called)
    monkeypatch.setattr(harness, "load_demonstrations", fail_if_called)
    assert main(["train", *model, "--data", str(tmp_path / "d.h5"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"driveopt: error: --out {out} cannot be written") and reason in err and err.count("\n") == 1
    assert not (tmp_path / "new").exists()


def test_train_rl_refuses_an_output_folder_on_a_full_disk_before_the_first_step(tmp_path, capsys, monkeypatch):
    """The RL trainers probe --out too, before the folder is made or an environment built."""
    pytest.importorskip("stable_baselines3")
    import errno
    import os

    from driveopt import files
    from driveopt.cli import main
    from driveopt.training import rl

    def disk_full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def fail_if_called(*args, **kwargs):
        pytest.fail("an environment was built before the output folder was checked")

    monkeypatch.setattr(files.os, "fsync", disk_full)
    monkeypatch.setattr(rl, "_vec_env", fail_if_called)
    out = tmp_path / "run"
    assert main(["train", "dqn", "--scenario", "two-lane-d1.0", "--steps", "5", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"driveopt: error: --out {out} cannot be written") and "No space left on device" in err
    assert err.count("\n") == 1 and not out.exists()
