"""``driveopt train vqvae``: the VQ-VAE of P2's learned sampler from multi-modal demonstrations, resumably.

Examples: every stored mode (:mod:`driveopt.data.modes`, schema version 2) of the rows the harness learns from
(:mod:`driveopt.training.harness`: status SUCCESS, not within ``crash_margin`` seconds of a collision, canonical
episode order, whole episodes held out or separate validation files), so one observation brings up to M distinct plans,
not only the executed one. Files without modes (schema version 1) hold nothing to learn from and are refused; a mode's
trajectory is ``W @ coeffs`` with the VQ-VAE's basis, which must match the files' ``num_nodes`` and ``horizon``. The
PixelCNN trainer (:mod:`driveopt.training.pixelcnn`) learns from the same examples with the same settings.

VQ-VAE (:mod:`driveopt.learned.vqvae`): AdamW with a step decay (no weight decay on the codebook). The codebook starts
as encoder outputs of random training examples; after every epoch each dead code (assigned to no training example in
that epoch) is re-seeded from a random encoder output (``reseed_dead_codes``), live codes untouched. History per
epoch: the loss terms of eq. 6, perplexity and dead codes, for training and validation, and the codes re-seeded.
Output: ``vqvae.ckpt`` (lowest validation loss, weights before that epoch's re-seeding), ``last.ckpt``,
``history.json``, written after every epoch; rerunning the same command resumes.
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

from driveopt.basis import make_basis
from driveopt.checks import ConfigError
from driveopt.config import BasisConfig
from driveopt.data.demonstrations import DatasetError, Demonstrations
from driveopt.learned import vqvae as vq
from driveopt.learned.cvae import Batch
from driveopt.training import harness

WEIGHTS = "vqvae.ckpt"  # the best epoch's weights in the output folder
RESEED_CANDIDATES = 1024  # [-] encoder outputs drawn from for re-seeding dead codes
INITIAL_CODEBOOK_KEY = 10**6  # folded into the run's key for the codebook's first seeding (epoch keys are 1, 2, ...)


@dataclasses.dataclass(frozen=True)
class TrainConfig(harness.BaseTrainConfig):
    """Settings of the VQ-VAE and PixelCNN trainers: the common ones (:class:`~driveopt.training.harness.BaseTrainConfig`;
    ``batch_size`` counts modes) and the VQ-VAE's re-seeding (recorded by the PixelCNN too, unused there)."""

    reseed_dead_codes: bool = True  # re-seed unused codes from encoder outputs after every epoch (VQ-VAE)

    OWN_SETTINGS_AFTER: ClassVar[str] = "crash_margin"

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.reseed_dead_codes, bool):
            raise ConfigError(f"{self.setting_name('reseed_dead_codes')} must be true or false, got {self.reseed_dead_codes!r}")


# ---------------------------------------------------------------------------------------------- examples


def mode_examples(data: Demonstrations, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row index, mode index), each (E,): every real mode of ``rows``, row by row, lowest cost first."""
    r, m = np.nonzero(data.modes.mask[rows])
    return rows[r], m


def mode_batch(data: Demonstrations, rows: np.ndarray, modes: np.ndarray, basis: BasisConfig) -> Batch:
    """Training examples: each mode's trajectory (W @ coefficients, (E, K, 2) [m]) with its row's observation,
    initial state and lane bounds."""
    W = make_basis(basis).W.astype(np.float32)
    coeffs = data.modes.coeffs[rows, modes].astype(np.float32)
    n = coeffs.shape[1] // 2
    trajectory = np.stack([coeffs[:, :n] @ W.T, coeffs[:, n:] @ W.T], axis=-1)
    return Batch(data.observation[rows], trajectory, data.init_x[rows], data.init_y[rows], data.lane_bounds[rows])


def check_modes(data: Demonstrations, paths: harness.Paths, basis: BasisConfig) -> None:
    """DatasetError unless the demonstrations of ``paths`` hold modes whose trajectories ``basis`` can rebuild."""
    if data.modes is None:
        raise DatasetError(f"{harness.describe_paths(paths)} hold no modes (schema version 1 demonstrations): the VQ-VAE learns from "
                           "several plans per step; collect demonstrations with this driveopt (driveopt collect --modes M)")
    for key, want in (("num_nodes", basis.num_nodes), ("horizon", basis.horizon)):
        if key in data.attrs and data.attrs[key] != want:
            raise DatasetError(f"{harness.describe_paths(paths)}: {key} = {data.attrs[key]} but the VQ-VAE's basis has {want}")
    if data.modes.coeffs.shape[-1] != 2 * basis.num_coeffs:
        raise DatasetError(f"{harness.describe_paths(paths)}: modes have {data.modes.coeffs.shape[-1]} coefficients, the VQ-VAE's "
                           f"basis (order {basis.order}) {2 * basis.num_coeffs}")


@dataclasses.dataclass(frozen=True)
class ModeExamples:
    """The split's rows and the examples (modes) of each side."""

    split: harness.Split
    train: Batch  # (E, ...) every mode of the training rows
    val: Batch  # (V, ...) every mode of the validation rows

    def row_counts(self) -> dict[str, int]:
        """Rows and modes of each side, as the checkpoints record them."""
        return {**self.split.row_counts(), "train_modes": len(self.train.observation),
                "validation_modes": len(self.val.observation)}


def load_mode_examples(data_paths: harness.Paths, validation_paths: harness.Paths | None, tcfg: TrainConfig,
                       basis: BasisConfig) -> ModeExamples:
    """The harness's split (:func:`~driveopt.training.harness.load_split`) and every mode of its rows as examples;
    DatasetError when a file holds no modes for ``basis`` or fewer than two training modes remain."""
    split = harness.load_split(data_paths, validation_paths, tcfg)
    check_modes(split.data, data_paths, basis)
    if split.held is not split.data:
        check_modes(split.held, validation_paths, basis)
    train_examples = mode_examples(split.data, split.train_rows)
    val_examples = mode_examples(split.held, split.val_rows)
    if len(train_examples[0]) < 2:
        raise DatasetError(f"only {len(train_examples[0])} modes in the usable training rows of {harness.describe_paths(data_paths)}: "
                           "collect more demonstrations")
    return ModeExamples(split, mode_batch(split.data, *train_examples, basis), mode_batch(split.held, *val_examples, basis))


# ------------------------------------------------------------------------------------------ jitted steps
# At module level, configurations static: trainings with equal settings share their compilations.


@functools.partial(jax.jit, static_argnames=("cfg",))
def encode_trajectories(params, normaliser: vq.Normaliser, trajectory, cfg: vq.VQVAEConfig):
    """(Z_e (B, L, D), code indices (B, L)) of trajectories (B, K, 2) [m]."""
    z_e = vq.encode(params, cfg, normaliser, trajectory)
    return z_e, vq.quantise(z_e, params["codebook"])[2]


@functools.partial(jax.jit, static_argnames=("cfg", "optimiser"))
def _training_step(params, opt_state, batch: Batch, normaliser: vq.Normaliser, cfg: vq.VQVAEConfig, optimiser):
    (value, terms), grads = jax.value_and_grad(vq.loss, has_aux=True)(params, cfg, normaliser, batch)
    updates, opt_state = optimiser.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state, value, terms


@functools.partial(jax.jit, static_argnames=("cfg",))
def _example_terms(params, normaliser: vq.Normaliser, batch: Batch, cfg: vq.VQVAEConfig):
    return vq.example_terms(params, cfg, normaliser, batch)


_reseed = jax.jit(vq.reseed_dead_codes)


def _not_codebook(params: dict[str, Any]) -> dict[str, Any]:
    """Weight-decay mask: every parameter but the codebook."""
    return {k: jax.tree_util.tree_map(lambda _: k != "codebook", v) for k, v in params.items()}


# ------------------------------------------------------------------------------------------- training


def train_vqvae(
    data_paths: harness.Paths,
    out_dir: str | Path,
    cfg: vq.VQVAEConfig = vq.VQVAEConfig(),
    tcfg: TrainConfig = TrainConfig(),
    *,
    validation_paths: harness.Paths | None = None,
    progress: bool = True,
    stop_after: int | None = None,
) -> dict[str, Any]:
    """Train (or resume training) the VQ-VAE into ``out_dir``; returns a summary with the history.

    The summary's ``weights`` is the path of ``vqvae.ckpt`` (None before an epoch wrote it); ``stop_after``
    returns after this many epochs of this call (for tests of resumption)."""
    out = harness.check_output_folder(out_dir, WEIGHTS)
    examples = load_mode_examples(data_paths, validation_paths, tcfg, cfg.basis)
    split = examples.split
    meta = {"config": cfg.to_dict(), "train_config": tcfg.record(), "data": split.record(), "lanes": split.lanes(),
            "rows": examples.row_counts()}
    key = jax.random.PRNGKey(tcfg.seed)
    batch_size, steps = harness.epoch_steps(len(examples.train.observation), tcfg.batch_size)
    optimiser = harness.make_optimiser(tcfg, steps, _not_codebook)
    params = vq.init_params(cfg, jax.random.fold_in(key, 0))
    fresh = {"params": params, "normaliser": vq.fit_normaliser(examples.train, cfg), "opt_state": optimiser.init(params)}

    def check(path: Path, stored: dict[str, Any]) -> None:
        harness.check_same_run(path, stored, tcfg, meta["data"], {"config": ("VQ-VAE configuration", cfg.to_dict())})

    run = harness.TrainingRun(out, vq.CHECKPOINT_KIND, WEIGHTS, meta)
    state = run.resume(fresh, check)
    trainer = VQVAEEpochs(cfg, tcfg, key, optimiser, state, examples, batch_size, steps)
    if not run.history:  # the codebook starts on the encoder's outputs: every code is "dead" before the first epoch
        trainer.seed_codebook()
    harness.run_epochs(run, trainer, tcfg, desc="train vqvae", progress=progress, stop_after=stop_after)
    return run.summary(best_val_loss=run.best)


class VQVAEEpochs(harness.EpochTrainer):
    """The VQ-VAE's epochs: minibatch steps of eq. 6 counting the codes used, validation, then dead codes re-seeded."""

    def __init__(self, cfg: vq.VQVAEConfig, tcfg: TrainConfig, key: jax.Array, optimiser: Any, state: dict[str, Any],
                 examples: ModeExamples, batch_size: int, steps: int) -> None:
        self.cfg, self.tcfg, self.key, self.optimiser = cfg, tcfg, key, optimiser
        self.params, self.opt_state = state["params"], state["opt_state"]
        self.normaliser = vq.Normaliser(*state["normaliser"])
        self.train, self.val = examples.train, examples.val
        self.batch_size, self.steps = batch_size, steps
        self.counts = np.zeros(cfg.codebook_size, np.int64)  # training examples per code in the last epoch

    def train_epoch(self, epoch: int, show: Callable[[str], None]) -> dict[str, Any]:
        sums = {"loss": 0.0, "reconstruction": 0.0, "codebook": 0.0, "commitment": 0.0}
        self.counts = np.zeros(self.cfg.codebook_size, np.int64)
        for idx in harness.minibatches(self.epoch_key(epoch), len(self.train.observation), self.batch_size, self.steps):
            batch = Batch(*(jnp.asarray(a[idx]) for a in self.train))
            self.params, self.opt_state, value, terms = _training_step(self.params, self.opt_state, batch, self.normaliser,
                                                                       self.cfg, self.optimiser)
            harness.accumulate(sums, value, terms)
            self.counts += np.asarray(terms["counts"])
        record: dict[str, Any] = {"epoch": epoch + 1, **harness.train_means(sums, self.steps),
                                  "train_perplexity": vq.perplexity(self.counts), "train_dead_codes": int(np.sum(self.counts == 0))}
        if len(self.val.observation):
            record.update(self.validate())
        return record

    def validate(self) -> dict[str, Any]:
        """The validation examples' mean loss terms, loss, perplexity and dead codes."""
        parts = harness.chunks(list(self.val), lambda *b: _example_terms(self.params, self.normaliser, Batch(*b), self.cfg))
        terms = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        counts = np.bincount(terms["indices"].ravel(), minlength=self.cfg.codebook_size)
        means = {k: float(np.mean(terms[k])) for k in ("reconstruction", "codebook", "commitment")}
        return {**{f"val_{k}": v for k, v in means.items()},
                "val_loss": means["reconstruction"] + means["codebook"] + self.cfg.beta * means["commitment"],
                "val_perplexity": vq.perplexity(counts), "val_dead_codes": int(np.sum(counts == 0))}

    def rank(self, record: dict[str, Any]) -> float:
        """The validation loss (without validation rows: the training loss)."""
        return record.get("val_loss", record["train_loss"])

    def after_ranking(self, epoch: int, record: dict[str, Any]) -> None:
        """Re-seed the codes no training example used in this epoch (not after the last epoch: those are the weights)."""
        record["reseeded"] = 0
        if self.tcfg.reseed_dead_codes and record["train_dead_codes"] and epoch + 1 < self.tcfg.epochs:
            self.reseed(jnp.asarray(self.counts), jax.random.fold_in(self.epoch_key(epoch), self.steps + 1))
            record["reseeded"] = record["train_dead_codes"]

    def seed_codebook(self) -> None:
        """The codebook of a fresh run: encoder outputs of random training examples."""
        self.reseed(jnp.zeros(self.cfg.codebook_size, jnp.int32), jax.random.fold_in(self.key, INITIAL_CODEBOOK_KEY))

    def reseed(self, counts: jax.Array, key: jax.Array) -> None:
        """Replace the codes with zero ``counts`` by encoder outputs of RESEED_CANDIDATES random training examples."""
        k_rows, k_codes = jax.random.split(key)
        examples = len(self.train.observation)
        pick = np.sort(np.random.default_rng(np.asarray(jax.random.key_data(k_rows))).permutation(examples)[:RESEED_CANDIDATES])
        z_e, _ = encode_trajectories(self.params, self.normaliser, jnp.asarray(self.train.trajectory[pick]), self.cfg)
        codebook = _reseed(self.params["codebook"], counts, z_e.reshape(-1, self.cfg.latent_dim), k_codes)
        self.params = {**self.params, "codebook": codebook}

    def weights_state(self) -> dict[str, Any]:
        return {"params": self.params, "normaliser": self.normaliser}

    def training_state(self) -> dict[str, Any]:
        return {"params": self.params, "normaliser": self.normaliser, "opt_state": self.opt_state}

    def describe(self, record: dict[str, Any]) -> str:
        return (f"train {record['train_loss']:.3f} val {record.get('val_loss', float('nan')):.3f} m^2 "
                f"perplexity {record['train_perplexity']:.1f} dead {record['train_dead_codes']}")
