"""``driveopt train vqvae`` and ``driveopt train pixelcnn``: P2's learned sampler from multi-modal demonstrations, resumably.

Examples: every stored mode (:mod:`driveopt.data.modes`, schema version 2) of the rows the CVAE would
learn from (status SUCCESS, not within ``crash_margin`` seconds of a collision), so one observation
brings up to M distinct plans, not only the executed one. Rows and the validation split are those
of :mod:`driveopt.training.cvae` (canonical episode order; whole episodes held out, drawn by
the seed, or separate validation files), and checkpoints record the same data fingerprints, so
the file order changes nothing and resuming on other data is refused. Files without modes (schema
version 1) hold nothing to learn from and are refused; a mode's trajectory is ``W @ coeffs`` with
the VQ-VAE's basis, which must match the files' ``num_nodes`` and ``horizon``.

VQ-VAE (:mod:`driveopt.learned.vqvae`): AdamW with a step decay (no weight decay on the codebook).
The codebook starts as encoder outputs of random training examples; after every epoch each dead
code (assigned to no training example in that epoch) is re-seeded from a random encoder output
(``reseed_dead_codes``), live codes untouched. History per epoch: the loss terms of eq. 6,
perplexity and dead codes, for training and validation, and the codes re-seeded. Output:
``vqvae.ckpt`` (lowest validation loss, weights before that epoch's re-seeding), ``last.ckpt``,
``history.json``.

PixelCNN (:mod:`driveopt.learned.pixelcnn`): the VQ-VAE (``vqvae.ckpt``) is frozen; its encoder
gives the code indices of every mode, and the PixelCNN learns them given the observation
(cross-entropy, nats per code; accuracy of the most likely code). Output: ``pixelcnn.ckpt`` (lowest
validation cross-entropy), which embeds the VQ-VAE's parameters and normaliser: the one file the
``vqvae`` planners load (``--weights``; shipped as ``vqvae-two-lane.ckpt`` / ``vqvae-four-lane.ckpt``).
It records a digest of the VQ-VAE's weights; resuming with another VQ-VAE is refused, and so is a
VQ-VAE trained for roads whose lane counts do not cover the PixelCNN's data.

Both write their checkpoints atomically after every epoch (:mod:`driveopt.learned.checkpoint`), so
an interruption loses at most the epoch in flight and rerunning the same command resumes;
settings are checked before the data is read, and a non-finite training loss stops with
:class:`~driveopt.training.cvae.TrainingError`.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import serialization

from driveopt.basis import make_basis
from driveopt.checks import ConfigError, check_count, check_number
from driveopt.config import BasisConfig
from driveopt.data.demonstrations import DatasetError, Demonstrations
from driveopt.learned import pixelcnn as px
from driveopt.learned import vqvae as vq
from driveopt.learned.checkpoint import CheckpointError, load_checkpoint, restore, save_checkpoint
from driveopt.learned.cvae import Batch
from driveopt.training.cvae import (
    TrainingError,
    _check_same_data,
    _make_folder,
    _rows,
    check_output_folder,
    data_record,
    epoch_bar,
    minibatches,
    road_lanes,
)

EVAL_CHUNK = 1024  # [-] examples per jitted evaluation call (the last chunk is padded: one compilation)
RESEED_CANDIDATES = 1024  # [-] encoder outputs drawn from for re-seeding dead codes


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Settings of both trainers (``reseed_dead_codes`` is the VQ-VAE's only)."""

    epochs: int = 60  # [-]
    batch_size: int = 256  # [-] examples (modes) per step
    learning_rate: float = 1e-3  # [-] AdamW initial rate
    weight_decay: float = 6e-5  # [-] not applied to the codebook
    decay_every: int = 20  # [epochs] step decay period
    decay_factor: float = 0.1  # [-]
    validation_fraction: float = 0.1  # [-] share of episodes held out
    train_episodes: int = 0  # [-] learn from only this many of the other episodes (0: all)
    crash_margin: float = 3.0  # [s] rows this close before a collision are left out
    reseed_dead_codes: bool = True  # re-seed unused codes from encoder outputs after every epoch (VQ-VAE)
    seed: int = 0  # [-] >= 0

    def __post_init__(self):
        for name, minimum in (("epochs", 1), ("batch_size", 1), ("decay_every", 1), ("train_episodes", 0), ("seed", 0)):
            check_count(f"TrainConfig.{name}", getattr(self, name), minimum)
        check_number("TrainConfig.learning_rate", self.learning_rate, 0.0, low_open=True)
        check_number("TrainConfig.weight_decay", self.weight_decay, 0.0)
        check_number("TrainConfig.decay_factor", self.decay_factor, 0.0, 1.0, low_open=True)
        check_number("TrainConfig.validation_fraction", self.validation_fraction, 0.0, 1.0, high_open=True)
        check_number("TrainConfig.crash_margin", self.crash_margin, 0.0, unit="s")
        if not isinstance(self.reseed_dead_codes, bool):
            raise ConfigError(f"TrainConfig.reseed_dead_codes must be true or false, got {self.reseed_dead_codes!r}")


# ---------------------------------------------------------------------------------------------- data


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


def _check_modes(data: Demonstrations, paths: Any, basis: BasisConfig) -> None:
    if data.modes is None:
        raise DatasetError(f"{_names(paths)} hold no modes (schema version 1 demonstrations): the VQ-VAE learns from "
                           "several plans per step; collect demonstrations with this driveopt (driveopt collect --modes M)")
    for key, want in (("num_nodes", basis.num_nodes), ("horizon", basis.horizon)):
        if key in data.attrs and data.attrs[key] != want:
            raise DatasetError(f"{_names(paths)}: {key} = {data.attrs[key]} but the VQ-VAE's basis has {want}")
    if data.modes.coeffs.shape[-1] != 2 * basis.num_coeffs:
        raise DatasetError(f"{_names(paths)}: modes have {data.modes.coeffs.shape[-1]} coefficients, the VQ-VAE's basis "
                           f"(order {basis.order}) {2 * basis.num_coeffs}")


def _names(paths: Any) -> str:
    return ", ".join(str(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths))


def _examples(data_paths, validation_paths, tcfg: TrainConfig, basis: BasisConfig):
    """(data, held, train rows, val rows, train examples (Batch), val examples (Batch)), modes checked."""
    data, held, train_rows, val_rows = _rows(data_paths, validation_paths, tcfg)
    _check_modes(data, data_paths, basis)
    if held is not data:
        _check_modes(held, validation_paths, basis)
    train_examples = mode_examples(data, train_rows)
    val_examples = mode_examples(held, val_rows)
    if len(train_examples[0]) < 2:
        raise DatasetError(f"only {len(train_examples[0])} modes in the usable training rows of {_names(data_paths)}: "
                           "collect more demonstrations")
    return data, held, train_rows, val_rows, mode_batch(data, *train_examples, basis), mode_batch(held, *val_examples, basis)


# ------------------------------------------------------------------------------------------ helpers


@functools.lru_cache(maxsize=16)  # one object per setting: the jitted steps below take it as a static argument
def _optimiser(tcfg: TrainConfig, steps_per_epoch: int, decay_mask: Any = None) -> optax.GradientTransformation:
    schedule = optax.exponential_decay(tcfg.learning_rate, transition_steps=tcfg.decay_every * steps_per_epoch,
                                       decay_rate=tcfg.decay_factor, staircase=True)
    return optax.adamw(schedule, weight_decay=tcfg.weight_decay, mask=decay_mask)


def _not_codebook(params: dict[str, Any]) -> dict[str, Any]:
    return {k: jax.tree_util.tree_map(lambda _: k != "codebook", v) for k, v in params.items()}


def _chunks(arrays: Sequence[np.ndarray], fn: Callable, chunk: int = EVAL_CHUNK) -> list[Any]:
    """``fn`` over fixed-size chunks (at most ``chunk``) of the leading axis of ``arrays`` (the last one padded by
    repeating row 0), outputs trimmed back to the real rows (host numpy)."""
    n = len(arrays[0])
    chunk = max(1, min(chunk, n))
    out = []
    for lo in range(0, n, chunk):
        idx = np.arange(lo, lo + chunk)
        real = int(np.sum(idx < n))
        idx = np.where(idx < n, idx, 0)
        result = jax.device_get(fn(*(jnp.asarray(a[idx]) for a in arrays)))
        out.append(jax.tree_util.tree_map(lambda a: np.asarray(a)[:real], result))
    return out


# Jitted steps at module level, configurations static: trainings with equal settings share their compilations.


@functools.partial(jax.jit, static_argnames=("cfg", "optimiser"))
def _vq_step(params, opt_state, batch: Batch, normaliser: vq.Normaliser, cfg: vq.VQVAEConfig, optimiser):
    (value, terms), grads = jax.value_and_grad(vq.loss, has_aux=True)(params, cfg, normaliser, batch)
    updates, opt_state = optimiser.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state, value, terms


@functools.partial(jax.jit, static_argnames=("cfg",))
def _vq_terms(params, normaliser: vq.Normaliser, batch: Batch, cfg: vq.VQVAEConfig):
    return vq.example_terms(params, cfg, normaliser, batch)


@functools.partial(jax.jit, static_argnames=("cfg",))
def _vq_encode(params, normaliser: vq.Normaliser, trajectory, cfg: vq.VQVAEConfig):
    """(Z_e (B, L, D), code indices (B, L))."""
    z_e = vq.encode(params, cfg, normaliser, trajectory)
    return z_e, vq.quantise(z_e, params["codebook"])[2]


_reseed = jax.jit(vq.reseed_dead_codes)


@functools.partial(jax.jit, static_argnames=("cfg",))
def _vq_features(normaliser: vq.Normaliser, observation, cfg: vq.VQVAEConfig):
    return vq.features(observation, normaliser, cfg)


@functools.partial(jax.jit, static_argnames=("cfg", "optimiser"))
def _px_step(params, opt_state, codes, feats, cfg: px.PixelCNNConfig, optimiser):
    (value, terms), grads = jax.value_and_grad(px.loss, has_aux=True)(params, cfg, codes, feats)
    updates, opt_state = optimiser.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state, value, terms


@functools.partial(jax.jit, static_argnames=("cfg",))
def _px_terms(params, codes, feats, cfg: px.PixelCNNConfig):
    """Per example: cross-entropy [nats per code] and accuracy, each (B,)."""
    logits = px.code_logits(params, cfg, codes, feats)
    return {"cross_entropy": jnp.mean(optax.softmax_cross_entropy_with_integer_labels(logits, codes), axis=-1),
            "accuracy": jnp.mean(jnp.argmax(logits, -1) == codes, axis=-1)}


def weights_digest(state: Any) -> str:
    """16 hex digits identifying a pytree of arrays (its flax state dict, msgpack-serialised)."""
    return hashlib.sha256(serialization.msgpack_serialize(serialization.to_state_dict(jax.device_get(state)))).hexdigest()[:16]


def _check_resume(path: Path, meta: dict[str, Any], expected: dict[str, Any], tcfg: TrainConfig, what: str) -> None:
    """CheckpointError unless ``path``'s meta has ``expected``'s network configurations, the same training settings
    (epochs aside) and the same data record."""
    for key in ("config", "vqvae_config"):
        if key in expected and meta.get(key) != json.loads(json.dumps(expected[key])):
            raise CheckpointError(f"{path} has another {what} configuration ({key}: {meta.get(key)}); use a new --out")
    stored = dict(meta.get("train_config", {}))
    mismatch = {k: (stored.get(k), v) for k, v in dataclasses.asdict(tcfg).items() if k != "epochs" and stored.get(k) != v}
    if mismatch:
        raise CheckpointError(f"{path} was trained with other settings {mismatch} (stored, now); use a new --out")
    _check_same_data(path, meta.get("data"), expected["data"])


def _finite_or_stop(record: dict[str, Any], epoch: int, tcfg: TrainConfig) -> None:
    if not math.isfinite(record["train_loss"]):
        raise TrainingError(f"training diverged in epoch {epoch + 1} (train loss {record['train_loss']}): "
                            f"lower the learning rate (now {tcfg.learning_rate:g})")


# ------------------------------------------------------------------------------------------- VQ-VAE


def train_vqvae(
    data_paths: str | Path | Sequence[str | Path],
    out_dir: str | Path,
    cfg: vq.VQVAEConfig = vq.VQVAEConfig(),
    tcfg: TrainConfig = TrainConfig(),
    *,
    validation_paths: str | Path | Sequence[str | Path] | None = None,
    progress: bool = True,
    stop_after: int | None = None,
) -> dict[str, Any]:
    """Train (or resume training) the VQ-VAE into ``out_dir``; returns a summary with the history.

    The summary's ``weights`` is the path of ``vqvae.ckpt`` (None before an epoch wrote it); ``stop_after``
    returns after this many epochs of this call (for tests of resumption)."""
    out = check_output_folder(out_dir, "vqvae.ckpt")
    data, held, train_rows, val_rows, train, val = _examples(data_paths, validation_paths, tcfg, cfg.basis)
    n_train = len(train.observation)
    batch_size = min(tcfg.batch_size, n_train)
    steps_per_epoch = n_train // batch_size
    optimiser = _optimiser(tcfg, steps_per_epoch, _not_codebook)
    meta_base = {"config": cfg.to_dict(), "train_config": dataclasses.asdict(tcfg), "data": data_record(data, held, val_rows),
                 "lanes": road_lanes(data, train_rows),
                 "rows": {"train": int(len(train_rows)), "validation": int(len(val_rows)),
                          "train_modes": int(n_train), "validation_modes": int(len(val.observation))}}

    key = jax.random.PRNGKey(tcfg.seed)
    params = vq.init_params(cfg, jax.random.fold_in(key, 0))
    normaliser = vq.fit_normaliser(train, cfg)
    opt_state = optimiser.init(params)
    history: list[dict[str, Any]] = []
    best = float("inf")
    last = out / "last.ckpt"
    if last.exists():
        meta, state = load_checkpoint(last, vq.CHECKPOINT_KIND)
        _check_resume(last, meta, meta_base, tcfg, "VQ-VAE")
        target = {"params": params, "normaliser": normaliser, "opt_state": opt_state}
        restored = restore(target, {k: state.get(k) for k in target}, last, "the training state")
        params, normaliser, opt_state = restored["params"], vq.Normaliser(*restored["normaliser"]), restored["opt_state"]
        history, best = list(meta.get("history", [])), float(meta.get("best", float("inf")))
    _make_folder(out)

    def reseed(params, counts, k):
        """Dead codes replaced by encoder outputs of RESEED_CANDIDATES random training examples."""
        k_rows, k_codes = jax.random.split(k)
        pick = np.sort(np.random.default_rng(np.asarray(jax.random.key_data(k_rows))).permutation(n_train)[:RESEED_CANDIDATES])
        z_e, _ = _vq_encode(params, normaliser, jnp.asarray(train.trajectory[pick]), cfg)
        return {**params, "codebook": _reseed(params["codebook"], counts, z_e.reshape(-1, cfg.latent_dim), k_codes)}

    if not history:  # the codebook starts on the encoder's outputs: every code is "dead" before the first epoch
        params = reseed(params, jnp.zeros(cfg.codebook_size, jnp.int32), jax.random.fold_in(key, 10**6))

    bar = epoch_bar(len(history), tcfg, stop_after, "train vqvae", progress)
    start = time.perf_counter()
    for epoch in bar:
        epoch_key = jax.random.fold_in(key, epoch + 1)
        sums = {"loss": 0.0, "reconstruction": 0.0, "codebook": 0.0, "commitment": 0.0}
        counts = np.zeros(cfg.codebook_size, np.int64)
        for idx in minibatches(epoch_key, n_train, batch_size, steps_per_epoch):
            batch = Batch(*(jnp.asarray(a[idx]) for a in train))
            params, opt_state, value, terms = _vq_step(params, opt_state, batch, normaliser, cfg, optimiser)
            sums["loss"] += float(value)
            for name in ("reconstruction", "codebook", "commitment"):
                sums[name] += float(terms[name])
            counts += np.asarray(terms["counts"])
        record: dict[str, Any] = {"epoch": epoch + 1, **{f"train_{k}": v / steps_per_epoch for k, v in sums.items()},
                                  "train_perplexity": vq.perplexity(counts), "train_dead_codes": int(np.sum(counts == 0))}
        _finite_or_stop(record, epoch, tcfg)
        if len(val.observation):
            parts = _chunks(list(val), lambda *b: _vq_terms(params, normaliser, Batch(*b), cfg))
            terms = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
            val_counts = np.bincount(terms["indices"].ravel(), minlength=cfg.codebook_size)
            means = {k: float(np.mean(terms[k])) for k in ("reconstruction", "codebook", "commitment")}
            record.update({f"val_{k}": v for k, v in means.items()},
                          val_loss=means["reconstruction"] + means["codebook"] + cfg.beta * means["commitment"],
                          val_perplexity=vq.perplexity(val_counts), val_dead_codes=int(np.sum(val_counts == 0)))
        score = record.get("val_loss", record["train_loss"])
        if score < best:
            best = score
            save_checkpoint(out / "vqvae.ckpt", vq.CHECKPOINT_KIND, {"params": params, "normaliser": normaliser},
                            {**meta_base, "epoch": epoch + 1, "history": [*history, record]})
        record["reseeded"] = 0
        if tcfg.reseed_dead_codes and record["train_dead_codes"] and epoch + 1 < tcfg.epochs:
            params = reseed(params, jnp.asarray(counts), jax.random.fold_in(epoch_key, steps_per_epoch + 1))
            record["reseeded"] = record["train_dead_codes"]
        history.append(record)
        save_checkpoint(last, vq.CHECKPOINT_KIND, {"params": params, "normaliser": normaliser, "opt_state": opt_state},
                        {**meta_base, "epoch": epoch + 1, "history": history, "best": best})
        (out / "history.json").write_text(json.dumps(history, indent=1))
        bar.set_postfix_str(f"train {record['train_loss']:.3f} val {record.get('val_loss', float('nan')):.3f} m^2 "
                            f"perplexity {record['train_perplexity']:.1f} dead {record['train_dead_codes']}")
    bar.close()
    weights = out / "vqvae.ckpt"
    return {"epochs": len(history), "history": history, "best_val_loss": best, "rows": meta_base["rows"],
            "seconds": time.perf_counter() - start, "out": str(out), "weights": str(weights) if weights.exists() else None}


# ----------------------------------------------------------------------------------------- PixelCNN


def train_pixelcnn(
    data_paths: str | Path | Sequence[str | Path],
    vqvae_path: str | Path,
    out_dir: str | Path,
    cfg: px.PixelCNNConfig | None = None,
    tcfg: TrainConfig = TrainConfig(),
    *,
    validation_paths: str | Path | Sequence[str | Path] | None = None,
    progress: bool = True,
    stop_after: int | None = None,
) -> dict[str, Any]:
    """Train (or resume training) the PixelCNN prior over the codes of the frozen VQ-VAE ``vqvae_path``.

    ``cfg`` defaults to P2's architecture sized for the VQ-VAE (:meth:`PixelCNNConfig.for_vqvae`); its
    sequence length and code count must be the VQ-VAE's. The summary's ``weights`` is ``pixelcnn.ckpt``."""
    out = check_output_folder(out_dir, "pixelcnn.ckpt")
    vq_cfg, vq_params, vq_norm, vq_meta = vq.load_vqvae(vqvae_path)
    cfg = cfg or px.PixelCNNConfig.for_vqvae(vq_cfg)
    if (cfg.num_latents, cfg.codebook_size) != (vq_cfg.num_latents, vq_cfg.codebook_size):
        raise ConfigError(f"the PixelCNN's {cfg.num_latents} positions x {cfg.codebook_size} codes must be the VQ-VAE's "
                          f"{vq_cfg.num_latents} x {vq_cfg.codebook_size} ({vqvae_path})")
    data, held, train_rows, val_rows, train, val = _examples(data_paths, validation_paths, tcfg, vq_cfg.basis)
    lanes = road_lanes(data, train_rows)
    trained_for = vq_meta.get("lanes")
    if isinstance(trained_for, list) and not set(lanes) <= set(trained_for):
        raise CheckpointError(f"{vqvae_path} was trained for {trained_for}-lane roads; these demonstrations are of "
                              f"{lanes}-lane roads: train a VQ-VAE on them")

    def codes_and_features(batch: Batch) -> tuple[np.ndarray, np.ndarray]:
        if not len(batch.observation):
            return np.zeros((0, cfg.num_latents), np.int32), np.zeros((0, vq_norm.feature_mean.shape[0]), np.float32)
        codes = np.concatenate(_chunks([batch.trajectory], lambda t: _vq_encode(vq_params, vq_norm, t, vq_cfg)[1]))
        feats = np.concatenate(_chunks([batch.observation], lambda o: _vq_features(vq_norm, o, vq_cfg)))
        return codes.astype(np.int32), feats.astype(np.float32)

    train_codes, train_feats = codes_and_features(train)
    val_codes, val_feats = codes_and_features(val)
    n_train = len(train_codes)
    batch_size = min(tcfg.batch_size, n_train)
    steps_per_epoch = n_train // batch_size
    optimiser = _optimiser(tcfg, steps_per_epoch)
    vq_state = {"params": vq_params, "normaliser": vq_norm}
    meta_base = {"config": cfg.to_dict(), "vqvae_config": vq_cfg.to_dict(),
                 "vqvae": {"digest": weights_digest(vq_state), "path": str(vqvae_path)},
                 "train_config": dataclasses.asdict(tcfg), "data": data_record(data, held, val_rows), "lanes": lanes,
                 "rows": {"train": int(len(train_rows)), "validation": int(len(val_rows)),
                          "train_modes": int(n_train), "validation_modes": int(len(val_codes))},
                 "codes_used": {"train": int(len(np.unique(train_codes))), "perplexity": vq.perplexity(
                     np.bincount(train_codes.ravel(), minlength=cfg.codebook_size))}}

    key = jax.random.PRNGKey(tcfg.seed)
    params = px.init_params(cfg, jax.random.fold_in(key, 0))
    opt_state = optimiser.init(params)
    history: list[dict[str, Any]] = []
    best = float("inf")
    last = out / "last.ckpt"
    if last.exists():
        meta, state = load_checkpoint(last, px.CHECKPOINT_KIND)
        if (meta.get("vqvae") or {}).get("digest") != meta_base["vqvae"]["digest"]:
            raise CheckpointError(f"{last} was trained on the codes of another VQ-VAE ({(meta.get('vqvae') or {}).get('path')}); "
                                  "resume with the same --vqvae, or use a new --out")
        _check_resume(last, meta, meta_base, tcfg, "PixelCNN")
        target = {"params": params, "opt_state": opt_state}
        restored = restore(target, {k: state.get(k) for k in target}, last, "the training state")
        params, opt_state = restored["params"], restored["opt_state"]
        history, best = list(meta.get("history", [])), float(meta.get("best", float("inf")))
    _make_folder(out)

    bar = epoch_bar(len(history), tcfg, stop_after, "train pixelcnn", progress)
    start = time.perf_counter()
    for epoch in bar:
        epoch_key = jax.random.fold_in(key, epoch + 1)
        sums = {"loss": 0.0, "accuracy": 0.0}
        for idx in minibatches(epoch_key, n_train, batch_size, steps_per_epoch):
            params, opt_state, value, terms = _px_step(params, opt_state, jnp.asarray(train_codes[idx]), jnp.asarray(train_feats[idx]),
                                                       cfg, optimiser)
            sums["loss"] += float(value)
            sums["accuracy"] += float(terms["accuracy"])
        record: dict[str, Any] = {"epoch": epoch + 1, **{f"train_{k}": v / steps_per_epoch for k, v in sums.items()}}
        _finite_or_stop(record, epoch, tcfg)
        if len(val_codes):
            parts = _chunks([val_codes, val_feats], lambda c, f: _px_terms(params, c, f, cfg))
            record.update(val_loss=float(np.mean(np.concatenate([p["cross_entropy"] for p in parts]))),
                          val_accuracy=float(np.mean(np.concatenate([p["accuracy"] for p in parts]))))
        history.append(record)
        score = record.get("val_loss", record["train_loss"])
        if score < best:
            best = score
            save_checkpoint(out / "pixelcnn.ckpt", px.CHECKPOINT_KIND, {"params": params, "vqvae": vq_state},
                            {**meta_base, "epoch": epoch + 1, "history": history})
        save_checkpoint(last, px.CHECKPOINT_KIND, {"params": params, "opt_state": opt_state},
                        {**meta_base, "epoch": epoch + 1, "history": history, "best": best})
        (out / "history.json").write_text(json.dumps(history, indent=1))
        bar.set_postfix_str(f"train {record['train_loss']:.3f} val {record.get('val_loss', float('nan')):.3f} nats/code")
    bar.close()
    weights = out / "pixelcnn.ckpt"
    return {"epochs": len(history), "history": history, "best_val_loss": best, "rows": meta_base["rows"],
            "codes_used": meta_base["codes_used"], "seconds": time.perf_counter() - start, "out": str(out),
            "weights": str(weights) if weights.exists() else None}
