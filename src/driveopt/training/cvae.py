"""``driveopt train cvae``: fit the CVAE to expert demonstrations, resumably.

Rows: planning steps whose plan met every constraint (status SUCCESS), leaving out the last
``crash_margin`` seconds before a collision, in the canonical episode order (sorted by scenario,
seed, episode and content: :meth:`~driveopt.data.demonstrations.Demonstrations.episode_rank`), so
the same demonstrations given in any file order train the same model. Validation: whole episodes
(``validation_fraction`` of them, drawn by the seed from that order), so no episode is split between
the two sets; or every usable row of separate validation files, so that models trained on different
data meet the same held-out set.

Optimiser: AdamW with a step decay (x ``decay_factor`` every ``decay_every`` epochs; P1:
x 0.1 every 10 of 80 epochs); beta rises linearly from 0 to ``beta`` over ``anneal_epochs``.

Validation reports, besides the loss terms, ``val_prior_best_of_16``: the median over held-out rows
of the best of 16 trajectories decoded from z ~ N(0, I) (what planning sees), in m^2.

Output folder: ``last.ckpt`` (everything needed to resume: parameters, optimiser state, epoch,
history, normaliser), ``cvae.ckpt`` (the weights with the lowest validation loss: what the
planner loads) and ``history.json``. Both checkpoints are written atomically after every epoch,
so an interruption loses at most the epoch in flight; rerunning the same command resumes.
Checkpoints record the data (``meta["data"]``: fingerprints of the training demonstrations and of the
held-out episodes, see :func:`data_record`) and the lane counts of the training roads
(``meta["lanes"]``, checked by the planner). A checkpoint made from other data, another validation
split or another configuration is refused with the reason, and so is one of an older driveopt that
records no split (its split depended on the order of the files). Settings are checked when
:class:`TrainConfig` is made and the output folder before the data is read, so bad input writes
nothing; a NaN or infinite training loss stops training with :class:`TrainingError`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
from tqdm import tqdm

from driveopt import files
from driveopt.checks import check_count, check_number
from driveopt.data.demonstrations import DatasetError, Demonstrations, load_demonstrations
from driveopt.errors import DriveoptError
from driveopt.learned.checkpoint import CheckpointError, load_checkpoint, restore, save_checkpoint
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
from driveopt.sim.scenarios import ScenarioError, get_scenario


class TrainingError(DriveoptError):
    """Training cannot go on: the loss became NaN or infinite (diverged)."""


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    epochs: int = 60  # [-]
    batch_size: int = 256  # [-] rows per step
    learning_rate: float = 1e-3  # [-] AdamW initial rate
    weight_decay: float = 6e-5  # [-] P1
    decay_every: int = 20  # [epochs] step decay period
    decay_factor: float = 0.1  # [-]
    beta: float = 1.0  # [-] KL weight after annealing (reconstruction is in m^2)
    anneal_epochs: int = 10  # [epochs] beta rises linearly from 0 over these
    validation_fraction: float = 0.1  # [-] share of episodes held out
    train_episodes: int = 0  # [-] learn from only this many of the other episodes (0: all); for learning curves
    crash_margin: float = 3.0  # [s] rows this close before a collision are left out
    seed: int = 0  # [-] >= 0

    def __post_init__(self):
        for name, minimum in (("epochs", 1), ("batch_size", 1), ("decay_every", 1), ("anneal_epochs", 0),
                              ("train_episodes", 0), ("seed", 0)):
            check_count(f"TrainConfig.{name}", getattr(self, name), minimum)
        check_number("TrainConfig.learning_rate", self.learning_rate, 0.0, low_open=True)
        check_number("TrainConfig.weight_decay", self.weight_decay, 0.0)
        check_number("TrainConfig.decay_factor", self.decay_factor, 0.0, 1.0, low_open=True)
        check_number("TrainConfig.beta", self.beta, 0.0)
        check_number("TrainConfig.validation_fraction", self.validation_fraction, 0.0, 1.0, high_open=True)
        check_number("TrainConfig.crash_margin", self.crash_margin, 0.0, unit="s")

    def beta_at(self, epoch: int) -> float:
        return self.beta * min(1.0, (epoch + 1) / self.anneal_epochs) if self.anneal_epochs else self.beta


def training_rows(data: Demonstrations, crash_margin: float) -> np.ndarray:
    """Indices of the rows to learn from (see the module docstring)."""
    return np.flatnonzero((data.status == 0) & (data.time_to_crash() > crash_margin))


def canonical_order(data: Demonstrations, rows: np.ndarray) -> np.ndarray:
    """``rows`` sorted by their episode's canonical rank, then by row (time within an episode): the same
    rows in the same order whatever the order of the files."""
    rank = data.episode_rank()[data.episode[rows]]
    return rows[np.lexsort((rows, rank))]


def drawn_episodes(data: Demonstrations, rows: np.ndarray, count: int, seed: int) -> np.ndarray:
    """(len(rows),) mask of the rows of ``count`` episodes drawn by ``seed`` from the episodes of ``rows``
    in their canonical order (file order does not change the draw)."""
    rank = data.episode_rank()[data.episode[rows]]
    chosen = np.random.default_rng(seed).permutation(np.unique(rank))[:count]
    return np.isin(rank, chosen)


def split_episodes(data: Demonstrations, rows: np.ndarray, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train rows, validation rows) with ``fraction`` of the episodes (at least one when fraction > 0
    and there are two) held out whole, drawn by ``seed`` (:func:`drawn_episodes`)."""
    episodes = len(np.unique(data.episode[rows]))
    held = int(round(fraction * episodes))
    if fraction > 0 and episodes > 1:
        held = max(held, 1)
    is_val = drawn_episodes(data, rows, held, seed)
    return rows[~is_val], rows[is_val]


def evaluation_rows(data: Demonstrations, validation: float, seed: int, max_rows: int) -> np.ndarray:
    """Rows of an offline evaluation, in canonical order: the usable rows (:func:`training_rows`, default margin); with
    ``validation`` > 0 only those a training with the same ``validation`` and ``seed`` holds out; at most ``max_rows``
    evenly spaced ones (0: all)."""
    rows = canonical_order(data, training_rows(data, TrainConfig().crash_margin))
    if validation > 0:
        rows = split_episodes(data, rows, validation, seed)[1]
    if max_rows and len(rows) > max_rows:
        rows = rows[np.linspace(0, len(rows) - 1, max_rows).round().astype(int)]
    return rows


def evaluation_road_rows(data: Demonstrations, validation: float, seed: int, max_rows: int, what: str) -> tuple[np.ndarray, int]:
    """(:func:`evaluation_rows`, their road's lane count); DatasetError when there are none or they span several lane
    counts (``what`` is learned per lane count, e.g. "the learned priors are")."""
    rows = evaluation_rows(data, validation, seed, max_rows)
    if len(rows) == 0:
        raise DatasetError("no usable rows to evaluate (feasible plans more than 3 s before a collision)")
    lanes = road_lanes(data, rows)
    if len(lanes) != 1:
        raise DatasetError(f"demonstrations of roads with {lanes} lanes: {what} per lane count, give one road")
    return rows, lanes[0]


def data_record(data: Demonstrations, held: Demonstrations, val_rows: np.ndarray) -> dict[str, Any]:
    """What a checkpoint records of its data: fingerprints (independent of the file order) of the training
    demonstrations and of the held-out episodes of ``held`` (those with rows in ``val_rows``), and their count."""
    episodes = np.unique(held.episode[val_rows])
    return {"train": data.fingerprint(), "validation": held.fingerprint(episodes), "validation_episodes": len(episodes)}


def road_lanes(data: Demonstrations, rows: np.ndarray) -> list[int]:
    """Sorted lane counts of the roads (registered scenarios) of the episodes of ``rows``."""
    names = np.unique(data.episodes["scenario"][np.unique(data.episode[rows])])
    try:
        return sorted({get_scenario(str(name)).lanes for name in names})
    except ScenarioError as exc:
        raise DatasetError(f"demonstrations of a scenario whose road is unknown, so the weights could not name their lane count: {exc}") from None


def make_batch(data: Demonstrations, rows: np.ndarray) -> Batch:
    return Batch(data.observation[rows], data.trajectory[rows], data.init_x[rows], data.init_y[rows], data.lane_bounds[rows])


def _optimiser(tcfg: TrainConfig, steps_per_epoch: int) -> optax.GradientTransformation:
    schedule = optax.exponential_decay(tcfg.learning_rate, transition_steps=tcfg.decay_every * steps_per_epoch,
                                       decay_rate=tcfg.decay_factor, staircase=True)
    return optax.adamw(schedule, weight_decay=tcfg.weight_decay)


def epoch_bar(done: int, tcfg: TrainConfig, stop_after: int | None, desc: str, progress: bool) -> tqdm:
    """Progress bar over the epochs still to run: from ``done`` (those in the history, on resume) to
    ``tcfg.epochs``, at most ``stop_after`` of them in this call."""
    last = tcfg.epochs if stop_after is None else min(tcfg.epochs, done + stop_after)
    return tqdm(range(done, last), initial=done, total=tcfg.epochs, desc=desc, unit="epoch", disable=not progress)


def minibatches(epoch_key: jax.Array, examples: int, batch_size: int, steps: int) -> list[np.ndarray]:
    """Row indices of one epoch's ``steps`` minibatches: a permutation of ``examples`` drawn from ``epoch_key``."""
    order = np.asarray(jax.random.permutation(jax.random.fold_in(epoch_key, 0), examples))
    return [order[i * batch_size:(i + 1) * batch_size] for i in range(steps)]


def train_cvae(
    data_paths: str | Path | Sequence[str | Path],
    out_dir: str | Path,
    cfg: CVAEConfig = CVAEConfig(),
    tcfg: TrainConfig = TrainConfig(),
    *,
    validation_paths: str | Path | Sequence[str | Path] | None = None,
    progress: bool = True,
    stop_after: int | None = None,
) -> dict[str, Any]:
    """Train (or resume training) into ``out_dir``; returns a summary with the history.

    validation_paths: demonstrations held out whole (``validation_fraction`` is then not used).
    stop_after: return after this many epochs of this call (for tests of resumption).
    The summary's ``weights`` is the path of ``cvae.ckpt``, or None when no epoch has written it yet.
    """
    out = check_output_folder(out_dir, "cvae.ckpt")
    data, held, train_rows, val_rows = _rows(data_paths, validation_paths, tcfg)
    train, val = make_batch(data, train_rows), make_batch(held, val_rows)
    batch_size = min(tcfg.batch_size, len(train_rows))
    steps_per_epoch = len(train_rows) // batch_size
    optimiser = _optimiser(tcfg, steps_per_epoch)
    meta_base = {"config": cfg.to_dict(), "train_config": dataclasses.asdict(tcfg), "data": data_record(data, held, val_rows),
                 "lanes": road_lanes(data, train_rows), "rows": {"train": int(len(train_rows)), "validation": int(len(val_rows))}}

    key = jax.random.PRNGKey(tcfg.seed)
    params = init_params(cfg, jax.random.fold_in(key, 0))
    normaliser = fit_normaliser(train, cfg)
    opt_state = optimiser.init(params)
    history: list[dict[str, float]] = []
    best = float("inf")
    last = out / "last.ckpt"
    if last.exists():
        params, normaliser, opt_state, history, best = _resume(last, cfg, tcfg, meta_base["data"], params, normaliser, opt_state)
    _make_folder(out)

    @jax.jit
    def step(params, opt_state, batch, key, beta):
        (value, terms), grads = jax.value_and_grad(loss, has_aux=True)(params, cfg, normaliser, batch, key, beta)
        updates, opt_state = optimiser.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, value, terms

    @jax.jit
    def evaluate(params, batch, key):
        k_loss, k_prior = jax.random.split(key)
        coverage = prior_coverage(params, cfg, normaliser, batch, k_prior)
        return {**loss_terms(params, cfg, normaliser, batch, k_loss), "prior_best_of_16": jnp.median(coverage)}

    bar = epoch_bar(len(history), tcfg, stop_after, "train cvae", progress)
    start = time.perf_counter()
    for epoch in bar:
        epoch_key = jax.random.fold_in(key, epoch + 1)
        beta = jnp.float32(tcfg.beta_at(epoch))
        sums = {"loss": 0.0, "reconstruction": 0.0, "kl": 0.0}
        for i, idx in enumerate(minibatches(epoch_key, len(train_rows), batch_size, steps_per_epoch)):
            batch = Batch(*(jnp.asarray(a[idx]) for a in train))
            params, opt_state, value, terms = step(params, opt_state, batch, jax.random.fold_in(epoch_key, i + 1), beta)
            sums["loss"] += float(value)
            sums["reconstruction"] += float(terms["reconstruction"])
            sums["kl"] += float(terms["kl"])
        record = {"epoch": epoch + 1, "beta": float(beta), **{f"train_{k}": v / steps_per_epoch for k, v in sums.items()}}
        if len(val_rows):
            terms = evaluate(params, Batch(*(jnp.asarray(a) for a in val)), jax.random.fold_in(epoch_key, steps_per_epoch + 1))
            record.update(val_reconstruction=float(terms["reconstruction"]), val_kl=float(terms["kl"]),
                          val_loss=float(terms["reconstruction"] + beta * terms["kl"]),
                          val_prior_best_of_16=float(terms["prior_best_of_16"]))
        if not math.isfinite(record["train_loss"]):
            raise TrainingError(f"training diverged in epoch {epoch + 1} (train loss {record['train_loss']}): "
                                f"lower the learning rate (now {tcfg.learning_rate:g})")
        history.append(record)
        # Once beta is at its final value, keep the weights with the lowest validation loss.
        score = record.get("val_loss", record["train_loss"])
        if epoch + 1 >= min(tcfg.anneal_epochs, tcfg.epochs) and score < best:
            best = score
            save_checkpoint(out / "cvae.ckpt", CHECKPOINT_KIND, {"params": params, "normaliser": normaliser}, {**meta_base, "epoch": epoch + 1, "history": history})
        save_checkpoint(last, CHECKPOINT_KIND, {"params": params, "normaliser": normaliser, "opt_state": opt_state},
                        {**meta_base, "epoch": epoch + 1, "history": history, "best": best})
        (out / "history.json").write_text(json.dumps(history, indent=1))
        bar.set_postfix_str(f"train {record['train_loss']:.3f} val {record.get('val_loss', float('nan')):.3f} m^2")
    bar.close()
    weights = out / "cvae.ckpt"
    return {"epochs": len(history), "history": history, "best_val_loss": best, "rows": meta_base["rows"],
            "seconds": time.perf_counter() - start, "out": str(out), "weights": str(weights) if weights.exists() else None}


def _rows(data_paths, validation_paths, tcfg: TrainConfig) -> tuple[Demonstrations, Demonstrations, np.ndarray, np.ndarray]:
    """(training data, validation data, train rows, validation rows), rows in canonical order."""
    data = load_demonstrations(data_paths)
    rows = canonical_order(data, training_rows(data, tcfg.crash_margin))
    if validation_paths:
        held = load_demonstrations(validation_paths)
        if held.fingerprint() == data.fingerprint() or set(_paths(validation_paths)) & set(_paths(data_paths)):
            raise DatasetError("the validation demonstrations must be other files than the training ones")
        train_rows, val_rows = rows, canonical_order(held, training_rows(held, tcfg.crash_margin))
    else:
        held = data
        train_rows, val_rows = split_episodes(data, rows, tcfg.validation_fraction, tcfg.seed)
    if tcfg.train_episodes:  # the validation episodes stay the same whatever the count
        train_rows = train_rows[drawn_episodes(data, train_rows, tcfg.train_episodes, tcfg.seed + 1)]
    if len(train_rows) < 2:
        raise DatasetError(f"only {len(train_rows)} usable training rows in {data_paths}: collect more demonstrations")
    return data, held, train_rows, val_rows


def check_output_folder(out_dir: str | Path, weights: str) -> Path:
    """``out_dir`` as a Path; CheckpointError, before anything is read or written, when it is an existing file
    (a trainer writes last.ckpt, ``weights`` and history.json there)."""
    return files.check_output_folder(out_dir, CheckpointError, f"last.ckpt, {weights}, history.json")


def _make_folder(out: Path) -> None:
    files.make_output_folder(out, CheckpointError, "last.ckpt and history.json")


def _paths(paths: str | Path | Sequence[str | Path]) -> list[Path]:
    return [Path(p).resolve() for p in ([paths] if isinstance(paths, (str, Path)) else paths)]


def _check_same_data(path: Path, stored: Any, now: dict[str, Any]) -> None:
    """CheckpointError unless the checkpoint's data record ``stored`` equals ``now`` (see :func:`data_record`)."""
    if not isinstance(stored, dict) or "validation" not in stored:
        raise CheckpointError(f"{path} records no validation split (written by an older driveopt, whose split depended "
                              "on the order of the files); use a new --out")
    if stored.get("train") != now["train"]:
        raise CheckpointError(f"{path} was trained on other demonstrations (data {stored.get('train')}, now {now['train']}); use a new --out")
    if stored != now:
        raise CheckpointError(f"{path} held out other validation episodes ({stored.get('validation_episodes')} episodes "
                              f"{stored.get('validation')}, now {now['validation_episodes']} episodes {now['validation']}); "
                              "resume with the same validation demonstrations, or use a new --out")


def _resume(path: Path, cfg: CVAEConfig, tcfg: TrainConfig, data: dict[str, Any], params, normaliser, opt_state):
    meta, state = load_checkpoint(path, CHECKPOINT_KIND)
    if meta.get("config") != json.loads(json.dumps(cfg.to_dict())):
        raise CheckpointError(f"{path} has another CVAE configuration: {meta.get('config')}; use a new --out")
    stored = dict(meta.get("train_config", {}))
    defaults = dataclasses.asdict(TrainConfig())  # settings added later read as their defaults
    mismatch = {k: (stored.get(k, defaults[k]), v) for k, v in dataclasses.asdict(tcfg).items()
                if k != "epochs" and stored.get(k, defaults[k]) != v}
    if mismatch:
        raise CheckpointError(f"{path} was trained with other settings {mismatch} (stored, now); use a new --out")
    _check_same_data(path, meta.get("data"), data)
    target = {"params": params, "normaliser": normaliser, "opt_state": opt_state}
    restored = restore(target, {k: state.get(k) for k in target}, path, "the training state")
    return restored["params"], Normaliser(*restored["normaliser"]), restored["opt_state"], list(meta.get("history", [])), float(meta.get("best", float("inf")))

