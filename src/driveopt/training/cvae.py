"""``driveopt train cvae``: fit the CVAE to expert demonstrations, resumably.

Rows, validation split, checkpoints and resumption are the harness's (:mod:`driveopt.training.harness`): the rows of
feasible plans not within ``crash_margin`` seconds of a collision, in canonical episode order; whole episodes held out
(or separate validation files); ``last.ckpt``, ``cvae.ckpt`` and ``history.json`` written after every epoch, so
rerunning the same command resumes, and a checkpoint of other data, another split or another configuration is refused.

Optimiser: AdamW with a step decay (x ``decay_factor`` every ``decay_every`` epochs; P1: x 0.1 every 10 of 80
epochs); beta rises linearly from 0 to ``beta`` over ``anneal_epochs``.

Validation reports, besides the loss terms, ``val_prior_best_of_16``: the median over held-out rows of the best of
16 trajectories decoded from z ~ N(0, I) (what planning sees), in m^2.

``cvae.ckpt`` holds the weights with the lowest validation loss once beta has reached its final value (what the
planner loads). Checkpoints record the data (``meta["data"]``, :func:`~driveopt.training.harness.data_record`) and the
lane counts of the training roads (``meta["lanes"]``, checked by the planner).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import optax

from driveopt.checks import check_count, check_number
from driveopt.data.demonstrations import Demonstrations
from driveopt.learned.cvae import (
    CHECKPOINT_KIND,
    Batch,
    CVAEConfig,
    Normaliser,
    fit_normaliser,
    init_params,
    loss,
    loss_terms,
    prior_coverage,
)
from driveopt.training import harness
from driveopt.training.harness import evaluation_road_rows, training_rows

# Also importable from here, where the benchmarks of the learned priors look for them.
__all__ = ["WEIGHTS", "TrainConfig", "evaluation_road_rows", "make_batch", "train_cvae", "training_rows"]

WEIGHTS = "cvae.ckpt"  # the best epoch's weights in the output folder


@dataclasses.dataclass(frozen=True)
class TrainConfig(harness.BaseTrainConfig):
    """The CVAE's settings: the common ones (:class:`~driveopt.training.harness.BaseTrainConfig`) and the KL weight."""

    beta: float = 1.0  # [-] KL weight after annealing (reconstruction is in m^2)
    anneal_epochs: int = 10  # [epochs] beta rises linearly from 0 over these

    OWN_SETTINGS_AFTER: ClassVar[str] = "decay_factor"

    def __post_init__(self) -> None:
        super().__post_init__()
        check_count(self.setting_name("anneal_epochs"), self.anneal_epochs, 0)
        check_number(self.setting_name("beta"), self.beta, 0.0)

    def beta_at(self, epoch: int) -> float:
        """The KL weight of epoch ``epoch`` (0-based): rising linearly to ``beta`` at epoch ``anneal_epochs``."""
        return self.beta * min(1.0, (epoch + 1) / self.anneal_epochs) if self.anneal_epochs else self.beta


def make_batch(data: Demonstrations, rows: np.ndarray) -> Batch:
    """The CVAE's examples of ``rows``: observation, executed trajectory, initial state and lane bounds."""
    return Batch(data.observation[rows], data.trajectory[rows], data.init_x[rows], data.init_y[rows], data.lane_bounds[rows])


def train_cvae(
    data_paths: harness.Paths,
    out_dir: str | Path,
    cfg: CVAEConfig = CVAEConfig(),
    tcfg: TrainConfig = TrainConfig(),
    *,
    validation_paths: harness.Paths | None = None,
    progress: bool = True,
    stop_after: int | None = None,
) -> dict[str, Any]:
    """Train (or resume training) into ``out_dir``; returns a summary with the history.

    validation_paths: demonstrations held out whole (``validation_fraction`` is then not used).
    stop_after: return after this many epochs of this call (for tests of resumption).
    The summary's ``weights`` is the path of ``cvae.ckpt``, or None when no epoch has written it yet.
    """
    out = harness.check_output_folder(out_dir, WEIGHTS)
    split = harness.load_split(data_paths, validation_paths, tcfg)
    train = make_batch(split.data, split.train_rows)
    meta = {"config": cfg.to_dict(), "train_config": tcfg.record(), "data": split.record(), "lanes": split.lanes(),
            "rows": split.row_counts()}
    key = jax.random.PRNGKey(tcfg.seed)
    batch_size, steps = harness.epoch_steps(len(split.train_rows), tcfg.batch_size)
    optimiser = harness.make_optimiser(tcfg, steps)
    params = init_params(cfg, jax.random.fold_in(key, 0))
    fresh = {"params": params, "normaliser": fit_normaliser(train, cfg), "opt_state": optimiser.init(params)}

    def check(path: Path, stored: dict[str, Any]) -> None:
        harness.check_same_run(path, stored, tcfg, meta["data"], {"config": ("CVAE configuration", cfg.to_dict())})

    run = harness.TrainingRun(out, CHECKPOINT_KIND, WEIGHTS, meta)
    state = run.resume(fresh, check)
    trainer = CVAEEpochs(cfg, tcfg, key, optimiser, state, train, make_batch(split.held, split.val_rows), batch_size, steps)
    harness.run_epochs(run, trainer, tcfg, desc="train cvae", progress=progress, stop_after=stop_after)
    return run.summary(best_val_loss=run.best)


class CVAEEpochs(harness.EpochTrainer):
    """The CVAE's epochs: minibatch steps of the ELBO with annealed beta, then the validation terms."""

    def __init__(self, cfg: CVAEConfig, tcfg: TrainConfig, key: jax.Array, optimiser: optax.GradientTransformation,
                 state: dict[str, Any], train: Batch, val: Batch, batch_size: int, steps: int) -> None:
        self.cfg, self.tcfg, self.key = cfg, tcfg, key
        self.params, self.opt_state = state["params"], state["opt_state"]
        self.normaliser = Normaliser(*state["normaliser"])
        self.train, self.val = train, val
        self.batch_size, self.steps = batch_size, steps
        self.step = _training_step(cfg, self.normaliser, optimiser)
        self.evaluate = _evaluation(cfg, self.normaliser)

    def train_epoch(self, epoch: int, show: Callable[[str], None]) -> dict[str, Any]:
        epoch_key = self.epoch_key(epoch)
        beta = jnp.float32(self.tcfg.beta_at(epoch))
        sums = {"loss": 0.0, "reconstruction": 0.0, "kl": 0.0}
        for i, idx in enumerate(harness.minibatches(epoch_key, len(self.train.observation), self.batch_size, self.steps)):
            batch = Batch(*(jnp.asarray(a[idx]) for a in self.train))
            self.params, self.opt_state, value, terms = self.step(self.params, self.opt_state, batch,
                                                                  jax.random.fold_in(epoch_key, i + 1), beta)
            harness.accumulate(sums, value, terms)
        record = {"epoch": epoch + 1, "beta": float(beta), **harness.train_means(sums, self.steps)}
        if len(self.val.observation):
            terms = self.evaluate(self.params, Batch(*(jnp.asarray(a) for a in self.val)),
                                  jax.random.fold_in(epoch_key, self.steps + 1))
            record.update(val_reconstruction=float(terms["reconstruction"]), val_kl=float(terms["kl"]),
                          val_loss=float(terms["reconstruction"] + beta * terms["kl"]),
                          val_prior_best_of_16=float(terms["prior_best_of_16"]))
        return record

    def rank(self, record: dict[str, Any]) -> float | None:
        """The validation loss (without validation rows: the training loss), once beta is at its final value."""
        if record["epoch"] < min(self.tcfg.anneal_epochs, self.tcfg.epochs):
            return None
        return record.get("val_loss", record["train_loss"])

    def weights_state(self) -> dict[str, Any]:
        return {"params": self.params, "normaliser": self.normaliser}

    def training_state(self) -> dict[str, Any]:
        return {"params": self.params, "normaliser": self.normaliser, "opt_state": self.opt_state}

    def describe(self, record: dict[str, Any]) -> str:
        return f"train {record['train_loss']:.3f} val {record.get('val_loss', float('nan')):.3f} m^2"


def _training_step(cfg: CVAEConfig, normaliser: Normaliser, optimiser: optax.GradientTransformation) -> Callable:
    """Jitted (params, opt_state, batch, key, beta) -> (params, opt_state, loss, terms): one AdamW step on the ELBO."""

    @jax.jit
    def step(params, opt_state, batch, key, beta):
        (value, terms), grads = jax.value_and_grad(loss, has_aux=True)(params, cfg, normaliser, batch, key, beta)
        updates, opt_state = optimiser.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, value, terms

    return step


def _evaluation(cfg: CVAEConfig, normaliser: Normaliser) -> Callable:
    """Jitted (params, batch, key) -> the loss terms of ``batch`` and the median best-of-16 prior coverage [m^2]."""

    @jax.jit
    def evaluate(params, batch, key):
        k_loss, k_prior = jax.random.split(key)
        coverage = prior_coverage(params, cfg, normaliser, batch, k_prior)
        return {**loss_terms(params, cfg, normaliser, batch, k_loss), "prior_best_of_16": jnp.median(coverage)}

    return evaluate
