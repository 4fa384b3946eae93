"""``driveopt train pixelcnn``: the PixelCNN prior of P2's learned sampler over a trained VQ-VAE's codes, resumably.

The VQ-VAE (``vqvae.ckpt`` of ``driveopt train vqvae``) is frozen; its encoder gives the code indices of every mode of
the rows the VQ-VAE trainer learns from (:func:`~driveopt.training.vqvae.load_mode_examples`, the same settings
:class:`~driveopt.training.vqvae.TrainConfig`), and the PixelCNN (:mod:`driveopt.learned.pixelcnn`) learns them given
the observation (cross-entropy, nats per code; accuracy of the most likely code). AdamW with a step decay.

Output: ``pixelcnn.ckpt`` (lowest validation cross-entropy), which embeds the VQ-VAE's parameters and normaliser: the
one file the ``vqvae`` planners load (``--weights``; shipped as ``vqvae-two-lane.ckpt`` / ``vqvae-four-lane.ckpt``);
``last.ckpt`` and ``history.json``, written after every epoch, so rerunning the same command resumes. Checkpoints
record a digest of the VQ-VAE's weights; resuming with another VQ-VAE is refused, and so is a VQ-VAE trained for roads
whose lane counts do not cover the PixelCNN's data.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import serialization

from driveopt.checks import ConfigError
from driveopt.learned import pixelcnn as px
from driveopt.learned import vqvae as vq
from driveopt.learned.checkpoint import CheckpointError
from driveopt.learned.cvae import Batch
from driveopt.training import harness
from driveopt.training.vqvae import TrainConfig, encode_trajectories, load_mode_examples

WEIGHTS = "pixelcnn.ckpt"  # the best epoch's weights (with the VQ-VAE's) in the output folder


def weights_digest(state: Any) -> str:
    """16 hex digits identifying a pytree of arrays (its flax state dict, msgpack-serialised)."""
    return hashlib.sha256(serialization.msgpack_serialize(serialization.to_state_dict(jax.device_get(state)))).hexdigest()[:16]


# ------------------------------------------------------------------------------------------ jitted steps
# At module level, configurations static: trainings with equal settings share their compilations.


@functools.partial(jax.jit, static_argnames=("cfg",))
def _features(normaliser: vq.Normaliser, observation, cfg: vq.VQVAEConfig):
    return vq.features(observation, normaliser, cfg)


@functools.partial(jax.jit, static_argnames=("cfg", "optimiser"))
def _training_step(params, opt_state, codes, feats, cfg: px.PixelCNNConfig, optimiser):
    (value, terms), grads = jax.value_and_grad(px.loss, has_aux=True)(params, cfg, codes, feats)
    updates, opt_state = optimiser.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state, value, terms


@functools.partial(jax.jit, static_argnames=("cfg",))
def _example_terms(params, codes, feats, cfg: px.PixelCNNConfig):
    """Per example: cross-entropy [nats per code] and accuracy, each (B,)."""
    logits = px.code_logits(params, cfg, codes, feats)
    return {"cross_entropy": jnp.mean(optax.softmax_cross_entropy_with_integer_labels(logits, codes), axis=-1),
            "accuracy": jnp.mean(jnp.argmax(logits, -1) == codes, axis=-1)}


# ------------------------------------------------------------------------------------------- inputs


def pixelcnn_config(cfg: px.PixelCNNConfig | None, vq_cfg: vq.VQVAEConfig, vqvae_path: str | Path) -> px.PixelCNNConfig:
    """``cfg`` (default: P2's architecture sized for the VQ-VAE); ConfigError unless its sequence length and code count
    are the VQ-VAE's."""
    cfg = cfg or px.PixelCNNConfig.for_vqvae(vq_cfg)
    if (cfg.num_latents, cfg.codebook_size) != (vq_cfg.num_latents, vq_cfg.codebook_size):
        raise ConfigError(f"the PixelCNN's {cfg.num_latents} positions x {cfg.codebook_size} codes must be the VQ-VAE's "
                          f"{vq_cfg.num_latents} x {vq_cfg.codebook_size} ({vqvae_path})")
    return cfg


def check_vqvae_roads(vq_meta: dict[str, Any], lanes: list[int], vqvae_path: str | Path) -> None:
    """CheckpointError when the VQ-VAE records the roads it was trained for and they do not cover ``lanes``."""
    trained_for = vq_meta.get("lanes")
    if isinstance(trained_for, list) and not set(lanes) <= set(trained_for):
        raise CheckpointError(f"{vqvae_path} was trained for {trained_for}-lane roads; these demonstrations are of "
                              f"{lanes}-lane roads: train a VQ-VAE on them")


def codes_and_features(batch: Batch, vq_cfg: vq.VQVAEConfig, vq_params: Any, vq_norm: vq.Normaliser,
                       num_latents: int) -> tuple[np.ndarray, np.ndarray]:
    """The PixelCNN's examples of ``batch``: the VQ-VAE's code indices of each trajectory (E, L) and the features of
    its observation (E, F)."""
    if not len(batch.observation):
        return np.zeros((0, num_latents), np.int32), np.zeros((0, vq_norm.feature_mean.shape[0]), np.float32)
    codes = np.concatenate(harness.chunks([batch.trajectory], lambda t: encode_trajectories(vq_params, vq_norm, t, vq_cfg)[1]))
    feats = np.concatenate(harness.chunks([batch.observation], lambda o: _features(vq_norm, o, vq_cfg)))
    return codes.astype(np.int32), feats.astype(np.float32)


def codes_used(codes: np.ndarray, codebook_size: int) -> dict[str, Any]:
    """How many distinct codes the training examples use, and their perplexity (what the checkpoints record)."""
    return {"train": len(np.unique(codes)), "perplexity": vq.perplexity(np.bincount(codes.ravel(), minlength=codebook_size))}


def check_resumable(path: Path, stored: dict[str, Any], meta: dict[str, Any], tcfg: TrainConfig) -> None:
    """CheckpointError unless the checkpoint's ``stored`` meta continues the run of ``meta``: trained on the codes of
    the same VQ-VAE (its weights' digest), with the same configurations, settings and data
    (:func:`~driveopt.training.harness.check_same_run`)."""
    recorded = stored.get("vqvae") or {}
    if recorded.get("digest") != meta["vqvae"]["digest"]:
        raise CheckpointError(f"{path} was trained on the codes of another VQ-VAE ({recorded.get('path')}); "
                              "resume with the same --vqvae, or use a new --out")
    expected = {"config": ("PixelCNN configuration", meta["config"]), "vqvae_config": ("VQ-VAE configuration", meta["vqvae_config"])}
    harness.check_same_run(path, stored, tcfg, meta["data"], expected)


# ------------------------------------------------------------------------------------------- training


def train_pixelcnn(
    data_paths: harness.Paths,
    vqvae_path: str | Path,
    out_dir: str | Path,
    cfg: px.PixelCNNConfig | None = None,
    tcfg: TrainConfig = TrainConfig(),
    *,
    validation_paths: harness.Paths | None = None,
    progress: bool = True,
    stop_after: int | None = None,
) -> dict[str, Any]:
    """Train (or resume training) the PixelCNN prior over the codes of the frozen VQ-VAE ``vqvae_path``.

    ``cfg`` defaults to P2's architecture sized for the VQ-VAE (:meth:`PixelCNNConfig.for_vqvae`); its
    sequence length and code count must be the VQ-VAE's. The summary's ``weights`` is ``pixelcnn.ckpt``."""
    out = harness.check_output_folder(out_dir, WEIGHTS)
    vq_cfg, vq_params, vq_norm, vq_meta = vq.load_vqvae(vqvae_path)
    cfg = pixelcnn_config(cfg, vq_cfg, vqvae_path)
    examples = load_mode_examples(data_paths, validation_paths, tcfg, vq_cfg.basis)
    lanes = examples.split.lanes()
    check_vqvae_roads(vq_meta, lanes, vqvae_path)
    train = codes_and_features(examples.train, vq_cfg, vq_params, vq_norm, cfg.num_latents)
    val = codes_and_features(examples.val, vq_cfg, vq_params, vq_norm, cfg.num_latents)
    vq_state = {"params": vq_params, "normaliser": vq_norm}
    meta = {"config": cfg.to_dict(), "vqvae_config": vq_cfg.to_dict(),
            "vqvae": {"digest": weights_digest(vq_state), "path": str(vqvae_path)},
            "train_config": tcfg.record(), "data": examples.split.record(), "lanes": lanes, "rows": examples.row_counts(),
            "codes_used": codes_used(train[0], cfg.codebook_size)}
    key = jax.random.PRNGKey(tcfg.seed)
    batch_size, steps = harness.epoch_steps(len(train[0]), tcfg.batch_size)
    optimiser = harness.make_optimiser(tcfg, steps)
    params = px.init_params(cfg, jax.random.fold_in(key, 0))
    run = harness.TrainingRun(out, px.CHECKPOINT_KIND, WEIGHTS, meta)
    state = run.resume({"params": params, "opt_state": optimiser.init(params)},
                       lambda path, stored: check_resumable(path, stored, meta, tcfg))
    trainer = PixelCNNEpochs(cfg, key, optimiser, state, vq_state, train, val, batch_size, steps)
    harness.run_epochs(run, trainer, tcfg, desc="train pixelcnn", progress=progress, stop_after=stop_after)
    return run.summary(best_val_loss=run.best, codes_used=meta["codes_used"])


class PixelCNNEpochs(harness.EpochTrainer):
    """The PixelCNN's epochs: minibatch steps of the codes' cross-entropy, then the validation cross-entropy."""

    def __init__(self, cfg: px.PixelCNNConfig, key: jax.Array, optimiser: Any, state: dict[str, Any], vq_state: dict[str, Any],
                 train: tuple[np.ndarray, np.ndarray], val: tuple[np.ndarray, np.ndarray], batch_size: int, steps: int) -> None:
        self.cfg, self.key, self.optimiser = cfg, key, optimiser
        self.params, self.opt_state, self.vq_state = state["params"], state["opt_state"], vq_state
        self.train, self.val = train, val  # (codes (E, L), features (E, F))
        self.batch_size, self.steps = batch_size, steps

    def train_epoch(self, epoch: int, show: Callable[[str], None]) -> dict[str, Any]:
        codes, feats = self.train
        sums = {"loss": 0.0, "accuracy": 0.0}
        for idx in harness.minibatches(self.epoch_key(epoch), len(codes), self.batch_size, self.steps):
            self.params, self.opt_state, value, terms = _training_step(self.params, self.opt_state, jnp.asarray(codes[idx]),
                                                                       jnp.asarray(feats[idx]), self.cfg, self.optimiser)
            harness.accumulate(sums, value, terms)
        record: dict[str, Any] = {"epoch": epoch + 1, **harness.train_means(sums, self.steps)}
        if len(self.val[0]):
            parts = harness.chunks(list(self.val), lambda c, f: _example_terms(self.params, c, f, self.cfg))
            record.update(val_loss=float(np.mean(np.concatenate([p["cross_entropy"] for p in parts]))),
                          val_accuracy=float(np.mean(np.concatenate([p["accuracy"] for p in parts]))))
        return record

    def rank(self, record: dict[str, Any]) -> float:
        """The validation cross-entropy (without validation rows: the training loss)."""
        return record.get("val_loss", record["train_loss"])

    def weights_state(self) -> dict[str, Any]:
        return {"params": self.params, "vqvae": self.vq_state}

    def training_state(self) -> dict[str, Any]:
        return {"params": self.params, "opt_state": self.opt_state}

    def describe(self, record: dict[str, Any]) -> str:
        return f"train {record['train_loss']:.3f} val {record.get('val_loss', float('nan')):.3f} nats/code"
