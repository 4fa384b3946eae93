"""``driveopt train cvae-multipliers``: fit [5]'s CVAE (set-points and initial multipliers) through the planner's
set-point QP and unrolled projection, resumably.

Rows, validation split, checkpoints and resumption are the harness's (:mod:`driveopt.training.harness`): feasible
plans not within ``crash_margin`` seconds of a collision, canonical episode order, whole episodes held out (or separate
validation files); ``last.ckpt``, ``cvae-multipliers.ckpt`` and ``history.json`` written after every epoch, so
rerunning the same command resumes, and a checkpoint of other data, another split, other settings, another network or
projection is refused. Each row is rebuilt into its planning problem (:func:`driveopt.data.replay.problem_from_row`)
with the planner's configuration adapted to the scenario's car (:func:`driveopt.training.filter.split_planner`), and
the loss (:func:`driveopt.learned.cvae_multipliers.loss`) runs ``unroll`` iterations of that planner's projection.

Defaults are [5]'s (``Behavioral Input Distribution Training.ipynb``, ``models/cvae_qp_stack.py``) where the 2-core CPU
allows: AdamW 2e-4, weight decay 6e-5, x0.1 every 30 epochs, 20 unrolled iterations, beta 3.5 reached after 4000
epochs (their schedule: ``step / 1000 * beta`` with ``step`` rising 0.25 an epoch), residual weight 1 and speed
weight 5e-4 (their ``0.5 * mean(2 * residual + 1e-3 * speed error)``). Their batch (8000) and epochs (180) are
options; the defaults here are 256 and 60.

``cvae-multipliers.ckpt`` keeps the epoch with the lowest validation reconstruction + residual_weight x residual (the
parts that do not change with beta; without validation rows, the training ones).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import optax

from driveopt.checks import ConfigError, check_count, check_number
from driveopt.config import PlannerConfig, ProjectionConfig
from driveopt.data.demonstrations import DatasetError
from driveopt.learned import cvae_multipliers as cm
from driveopt.training import cvae as cvae_training
from driveopt.training import harness
from driveopt.training.filter import row_problems, split_planner

WEIGHTS = "cvae-multipliers.ckpt"  # the best epoch's weights in the output folder
TERMS = ("reconstruction", "kl", "residual", "velocity", "feasible")


@dataclasses.dataclass(frozen=True)
class TrainConfig(cvae_training.TrainConfig):
    """The settings: the CVAE's (:class:`driveopt.training.cvae.TrainConfig`, [5]'s defaults) and the unrolled stack's."""

    learning_rate: float = 2e-4  # [-] [5]
    decay_every: int = 30  # [epochs] [5]: x0.1 every 30 epochs
    beta: float = 3.5  # [-] [5]
    anneal_epochs: int = 4000  # [epochs] [5]'s schedule reaches beta after 4000 epochs
    unroll: int = 20  # [-] projection iterations unrolled ([5]: 20)
    residual_weight: float = 1.0  # [m^2] per unit of total residual ([5]: 0.5 x twice the last iteration's)
    velocity_weight: float = 5e-4  # [m^2 s/m] per m/s of speed error's L2 norm over the nodes ([5]: 0.5 x 1e-3)

    OWN_SETTINGS_AFTER: ClassVar[str] = "decay_factor"

    def __post_init__(self) -> None:
        super().__post_init__()
        check_count(self.setting_name("unroll"), self.unroll, 1)
        check_number(self.setting_name("residual_weight"), self.residual_weight, 0.0, unit="m^2")
        check_number(self.setting_name("velocity_weight"), self.velocity_weight, 0.0)


def training_config(config: PlannerConfig, tcfg: TrainConfig) -> PlannerConfig:
    """``config`` with ``tcfg.unroll`` projection iterations (what the loss unrolls)."""
    return config.replace(projection={"max_iterations": tcfg.unroll})


def make_batch(problems: cm.PlanningProblem, trajectory: np.ndarray, idx: np.ndarray) -> cm.Batch:
    """The rows ``idx`` of stacked ``problems`` and expert ``trajectory`` (R, K, 2), as device arrays."""
    return cm.Batch(jax.tree_util.tree_map(lambda a: jnp.asarray(a[idx]), problems), jnp.asarray(trajectory[idx]))


@functools.partial(jax.jit, static_argnames=("cfg", "config", "optimiser"))
def _step(params, opt_state, norm, batch, key, beta, residual_weight, velocity_weight, cfg, config, optimiser):
    (value, terms), grads = jax.value_and_grad(cm.loss, has_aux=True)(params, cfg, norm, batch, key, config, beta,
                                                                      residual_weight, velocity_weight)
    updates, opt_state = optimiser.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state, value, terms


@functools.partial(jax.jit, static_argnames=("cfg", "config"))
def _row_terms(params, norm, batch, key, cfg, config):
    return cm.batch_terms(params, cfg, norm, batch, key, config)


@dataclasses.dataclass(frozen=True)
class Rows:
    """The examples of one side of the split: stacked planning problems and expert trajectories."""

    problems: Any  # PlanningProblem, numpy, R leading
    trajectory: np.ndarray  # (R, K, 2) [m]

    def __len__(self) -> int:
        return len(self.trajectory)


def train_cvae_multipliers(
    data_paths: harness.Paths,
    out_dir: str | Path,
    cfg: cm.MultiplierCVAEConfig = cm.MultiplierCVAEConfig(),
    tcfg: TrainConfig = TrainConfig(),
    *,
    config: PlannerConfig,
    validation_paths: harness.Paths | None = None,
    progress: bool = True,
    stop_after: int | None = None,
) -> dict[str, Any]:
    """Train (or resume training) into ``out_dir`` for the planning configuration ``config`` (the planner's set-point
    QP and projection); returns a summary with the history. ConfigError when the network's basis is not the
    planner's (before any data is read); DatasetError for unusable demonstrations."""
    if cfg.cvae.basis != config.basis:
        raise ConfigError(f"the network's basis {cfg.cvae.basis} is not the planner's {config.basis}")
    out = harness.check_output_folder(out_dir, WEIGHTS)
    split = harness.load_split(data_paths, validation_paths, tcfg)
    if split.data.coeffs.shape[-1] != cfg.num_coeffs:
        raise DatasetError(f"the demonstrations' plans have {split.data.coeffs.shape[-1]} coefficients, the network's "
                           f"basis {cfg.num_coeffs}")
    planner, v_des = split_planner(split, config)
    run_config = training_config(planner, tcfg)
    train = Rows(row_problems(split.data, split.train_rows, v_des, run_config), split.data.trajectory[split.train_rows])
    val = Rows(row_problems(split.held, split.val_rows, v_des, run_config), split.held.trajectory[split.val_rows]) \
        if len(split.val_rows) else None
    meta = {"config": cfg.to_dict(), "train_config": tcfg.record(), "data": split.record(), "lanes": split.lanes(),
            "projection": dataclasses.asdict(run_config.projection), "rows": split.row_counts()}
    key = jax.random.PRNGKey(tcfg.seed)
    batch_size, steps = harness.epoch_steps(len(train), tcfg.batch_size)
    optimiser = harness.make_optimiser(tcfg, steps)
    params = cm.init_params(cfg, jax.random.fold_in(key, 0))
    rows = split.train_rows
    normaliser = cm.fit_normaliser(split.data.observation[rows], split.data.trajectory[rows], split.data.coeffs[rows],
                                   split.data.init_y[rows, 0], cfg)

    def check(path: Path, stored: dict[str, Any]) -> None:
        recorded = dict(stored)
        if isinstance(stored.get("projection"), dict):  # a projection setting added since ran at its default
            recorded["projection"] = {**dataclasses.asdict(ProjectionConfig()), **stored["projection"]}
        harness.check_same_run(path, recorded, tcfg, meta["data"], {"config": ("network configuration", meta["config"]),
                                                                    "projection": ("projection", meta["projection"])})

    run = harness.TrainingRun(out, cm.CHECKPOINT_KIND, WEIGHTS, meta)
    state = run.resume({"params": params, "normaliser": normaliser, "opt_state": optimiser.init(params)}, check)
    trainer = MultiplierEpochs(cfg, tcfg, run_config, key, optimiser, state, train, val, batch_size, steps)
    harness.run_epochs(run, trainer, tcfg, desc="train cvae-multipliers", progress=progress, stop_after=stop_after)
    return run.summary(best=run.best)


class MultiplierEpochs(harness.EpochTrainer):
    """The epochs: minibatch steps of the loss with annealed beta, then the validation terms (one fixed key)."""

    def __init__(self, cfg: cm.MultiplierCVAEConfig, tcfg: TrainConfig, config: PlannerConfig, key: jax.Array,
                 optimiser: optax.GradientTransformation, state: dict[str, Any], train: Rows, val: Rows | None,
                 batch_size: int, steps: int) -> None:
        self.cfg, self.tcfg, self.config, self.key, self.optimiser = cfg, tcfg, config, key, optimiser
        self.params, self.opt_state = state["params"], state["opt_state"]
        self.normaliser = cm.Normaliser(*state["normaliser"])
        self.train, self.val, self.batch_size, self.steps = train, val, batch_size, steps
        self.weights = (jnp.float32(tcfg.residual_weight), jnp.float32(tcfg.velocity_weight))

    def train_epoch(self, epoch: int, show: Callable[[str], None]) -> dict[str, Any]:
        epoch_key = self.epoch_key(epoch)
        beta = jnp.float32(self.tcfg.beta_at(epoch))
        sums = {"loss": 0.0, **{name: 0.0 for name in TERMS}}
        for i, idx in enumerate(harness.minibatches(epoch_key, len(self.train), self.batch_size, self.steps)):
            batch = make_batch(self.train.problems, self.train.trajectory, idx)
            self.params, self.opt_state, value, terms = _step(
                self.params, self.opt_state, self.normaliser, batch, jax.random.fold_in(epoch_key, i + 1), beta,
                *self.weights, cfg=self.cfg, config=self.config, optimiser=self.optimiser)
            harness.accumulate(sums, value, terms)
            show(f"step {i + 1}/{self.steps} train {sums['loss'] / (i + 1):.3f}")
        record = {"epoch": epoch + 1, "beta": float(beta), **harness.train_means(sums, self.steps)}
        if self.val is not None:
            record.update({f"val_{k}": v for k, v in self.validation_terms().items()})
        return record

    def validation_terms(self) -> dict[str, float]:
        """Means over the validation rows of the loss terms (``batch_size`` rows a call, one key for every epoch)."""
        key = jax.random.PRNGKey(self.tcfg.seed + 1)
        leaves, treedef = jax.tree_util.tree_flatten(self.val.problems)
        parts = harness.chunks([*leaves, self.val.trajectory], lambda *a: _row_terms(
            self.params, self.normaliser, cm.Batch(jax.tree_util.tree_unflatten(treedef, a[:-1]), a[-1]), key, self.cfg,
            self.config), self.batch_size)
        return {k: float(np.mean(np.concatenate([part[k] for part in parts]))) for k in TERMS}

    def rank(self, record: dict[str, Any]) -> float:
        """Reconstruction + residual_weight x residual on the validation rows (the training rows without them)."""
        split = "val" if "val_reconstruction" in record else "train"
        return record[f"{split}_reconstruction"] + self.tcfg.residual_weight * record[f"{split}_residual"]

    def weights_state(self) -> dict[str, Any]:
        return {"params": self.params, "normaliser": self.normaliser}

    def training_state(self) -> dict[str, Any]:
        return {"params": self.params, "normaliser": self.normaliser, "opt_state": self.opt_state}

    def describe(self, record: dict[str, Any]) -> str:
        return f"train {record['train_loss']:.3f} residual {record.get('val_residual', record['train_residual']):.3f}"
