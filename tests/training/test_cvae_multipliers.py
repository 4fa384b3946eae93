"""Training [5]'s CVAE through the unrolled projection (training.cvae_multipliers): the loss falls on a tiny dataset,
the best weights load, a resumed run with other settings is refused, and the command is wired."""

from __future__ import annotations

import math

import pytest
from learned_data import file_fixture, trained_fixture, write_scenes

from driveopt.checks import ConfigError
from driveopt.cli import main
from driveopt.learned import cvae_multipliers as cm
from driveopt.learned.checkpoint import CheckpointError
from driveopt.learned.cvae import CVAEConfig
from driveopt.registry import get_optimiser
from driveopt.training.cvae_multipliers import TrainConfig, train_cvae_multipliers

CFG = cm.MultiplierCVAEConfig(cvae=CVAEConfig(hidden=(16,)), multiplier_hidden=(16,))
TCFG = TrainConfig(epochs=4, batch_size=8, unroll=1, learning_rate=1e-2, beta=0.1, anneal_epochs=1, validation_fraction=0.34)
CONFIG = get_optimiser("cvae-multipliers").config

data_file = file_fixture(lambda path: write_scenes(path, episodes=3, rows=8), "scenes.h5")
trained = trained_fixture(lambda data, out: train_cvae_multipliers(data, out, CFG, TCFG, config=CONFIG, progress=False))


def test_the_loss_falls_and_the_best_weights_load(trained):
    out, summary = trained
    history = summary["history"]
    assert len(history) == TCFG.epochs and all(math.isfinite(r["train_loss"]) for r in history)
    assert history[-1]["train_loss"] < 0.7 * history[0]["train_loss"]
    assert {"val_reconstruction", "val_residual", "val_feasible"} <= set(history[-1])
    cfg, _, _, meta = cm.load_model(summary["weights"], lanes=4)
    assert cfg == CFG and meta["projection"]["max_iterations"] == TCFG.unroll and meta["lanes"] == [4]
    assert (out / "last.ckpt").exists() and (out / "history.json").exists()


def test_resuming_with_other_settings_or_another_basis_is_refused(trained, data_file):
    out, _ = trained
    with pytest.raises(CheckpointError, match="other settings"):
        train_cvae_multipliers(data_file, out, CFG, TrainConfig(**{**TCFG.record(), "residual_weight": 2.0}),
                               config=CONFIG, progress=False)
    with pytest.raises(CheckpointError, match="another projection"):
        train_cvae_multipliers(data_file, out, CFG, TrainConfig(**{**TCFG.record(), "unroll": 3}), config=CONFIG,
                               progress=False)
    with pytest.raises(ConfigError, match="basis"):
        train_cvae_multipliers(data_file, out, CFG, TCFG, config=CONFIG.replace(basis={"order": 8}), progress=False)
    with pytest.raises(ConfigError, match="unroll"):
        TrainConfig(unroll=0)


def test_the_train_command_is_wired_and_refuses_missing_data(tmp_path, capsys):
    assert main(["train", "cvae-multipliers", "--data", str(tmp_path / "missing.h5"), "--out", str(tmp_path / "o")]) == 2
    assert "missing.h5" in capsys.readouterr().err
