"""What every trainer shares: its common settings, the rows it learns from and their held-out split, batching, the
optimiser, and the resumable epoch loop that keeps the best checkpoint.

Rows (:func:`load_split`): planning steps whose plan met every constraint (status SUCCESS), leaving out the last
``crash_margin`` seconds before a collision, in the canonical episode order (sorted by scenario, seed, episode and
content: :meth:`~driveopt.data.demonstrations.Demonstrations.episode_rank`), so the same demonstrations given in any
file order train the same model. Validation: whole episodes (``validation_fraction`` of them, drawn by the seed from
that order), so no episode is split between the two sets; or every usable row of separate validation files, so that
models trained on different data meet the same held-out set. ``train_episodes`` keeps only that many of the other
episodes (for learning curves); the held-out ones stay the same whatever the count.

Optimiser (:func:`make_optimiser`): AdamW whose rate is multiplied by ``decay_factor`` every ``decay_every`` epochs.

Epoch loop (:func:`run_epochs`): after every epoch it writes, atomically (:mod:`driveopt.learned.checkpoint`),
``last.ckpt`` (everything needed to resume: parameters, optimiser state, normaliser, epoch, history), the trainer's
weights file (the best epoch by the trainer's rank: what the planner loads) and ``history.json``. An interruption
loses at most the epoch in flight, and rerunning the same command resumes: every minibatch and random draw follows
from the seed and the epoch, so a resumed run writes the same files as an uninterrupted one. Checkpoints record the
data (:func:`data_record`); resuming on other data, another validation split, other settings or another configuration
is refused with the reason (:func:`check_same_run`), and so is a checkpoint of an older driveopt that records no split
(its split depended on the order of the files). A NaN or infinite training loss stops training with
:class:`TrainingError`.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

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
from driveopt.sim.scenarios import ScenarioError, get_scenario

Paths = str | Path | Sequence[str | Path]  # one demonstration file or several

CRASH_MARGIN = 3.0  # [s] default: rows this close before a collision are not learned from
EVAL_CHUNK = 1024  # [-] examples per jitted evaluation call (the last chunk is padded: one compilation)
LAST = "last.ckpt"  # the resume state in the output folder
HISTORY = "history.json"  # one record per finished epoch


class TrainingError(DriveoptError):
    """Training cannot go on: the loss became NaN or infinite (diverged)."""


# ------------------------------------------------------------------------------------------- settings


@dataclasses.dataclass(frozen=True)
class BaseTrainConfig:
    """The settings every trainer has; each trainer's ``TrainConfig`` adds its own (and may change the defaults).

    Checkpoints record the settings (:meth:`record`) in a fixed order: these common ones as listed here, with the
    trainer's own inserted after ``OWN_SETTINGS_AFTER``. The order is part of a checkpoint's header, so keeping it
    keeps the checkpoints a trainer writes byte for byte what it has always written.
    """

    epochs: int = 60  # [-] passes over the training examples
    batch_size: int = 256  # [-] examples per optimiser step (at most the number of training examples)
    learning_rate: float = 1e-3  # [-] AdamW initial rate
    weight_decay: float = 6e-5  # [-] AdamW decoupled weight decay (P1)
    decay_every: int = 20  # [epochs] step decay period of the learning rate
    decay_factor: float = 0.1  # [-] learning-rate multiplier every decay_every epochs, in (0, 1]
    validation_fraction: float = 0.1  # [-] share of episodes held out, in [0, 1)
    train_episodes: int = 0  # [-] learn from only this many of the other episodes (0: all); for learning curves
    crash_margin: float = CRASH_MARGIN  # [s] rows this close before a collision are left out
    seed: int = 0  # [-] >= 0: initialisation, split, minibatches and every random draw

    OWN_SETTINGS_AFTER: ClassVar[str] = "seed"  # the common setting after which checkpoints list the trainer's own

    def __post_init__(self) -> None:
        for name, minimum in (("epochs", 1), ("batch_size", 1), ("decay_every", 1), ("train_episodes", 0), ("seed", 0)):
            check_count(self.setting_name(name), getattr(self, name), minimum)
        check_number(self.setting_name("learning_rate"), self.learning_rate, 0.0, low_open=True)
        check_number(self.setting_name("weight_decay"), self.weight_decay, 0.0)
        check_number(self.setting_name("decay_factor"), self.decay_factor, 0.0, 1.0, low_open=True)
        check_number(self.setting_name("validation_fraction"), self.validation_fraction, 0.0, 1.0, high_open=True)
        check_number(self.setting_name("crash_margin"), self.crash_margin, 0.0, unit="s")

    def setting_name(self, name: str) -> str:
        """How error messages name the setting ``name``, e.g. ``TrainConfig.learning_rate``."""
        return f"{type(self).__name__}.{name}"

    def record(self) -> dict[str, Any]:
        """The settings as checkpoints record them (``meta["train_config"]``), in the order described above."""
        values = dataclasses.asdict(self)
        common = [f.name for f in dataclasses.fields(BaseTrainConfig)]
        own = [name for name in values if name not in common]
        split = common.index(self.OWN_SETTINGS_AFTER) + 1
        return {name: values[name] for name in [*common[:split], *own, *common[split:]]}


# ----------------------------------------------------------------------------------------- rows and split


def training_rows(data: Demonstrations, crash_margin: float) -> np.ndarray:
    """Indices of the rows to learn from: status SUCCESS and more than ``crash_margin`` [s] before a collision."""
    return np.flatnonzero((data.status == 0) & (data.time_to_crash() > crash_margin))


def canonical_order(data: Demonstrations, rows: np.ndarray) -> np.ndarray:
    """``rows`` sorted by their episode's canonical rank, then by row (time within an episode): the same rows in the
    same order whatever the order of the files."""
    rank = data.episode_rank()[data.episode[rows]]
    return rows[np.lexsort((rows, rank))]


def drawn_episodes(data: Demonstrations, rows: np.ndarray, count: int, seed: int) -> np.ndarray:
    """(len(rows),) mask of the rows of ``count`` episodes drawn by ``seed`` from the episodes of ``rows`` in their
    canonical order (file order does not change the draw)."""
    rank = data.episode_rank()[data.episode[rows]]
    chosen = np.random.default_rng(seed).permutation(np.unique(rank))[:count]
    return np.isin(rank, chosen)


def split_episodes(data: Demonstrations, rows: np.ndarray, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train rows, validation rows) with ``fraction`` of the episodes (at least one when fraction > 0 and there are
    two) held out whole, drawn by ``seed`` (:func:`drawn_episodes`)."""
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
    rows = canonical_order(data, training_rows(data, CRASH_MARGIN))
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
        raise DatasetError(f"no usable rows to evaluate (feasible plans more than {CRASH_MARGIN:g} s before a collision)")
    lanes = road_lanes(data, rows)
    if len(lanes) != 1:
        raise DatasetError(f"demonstrations of roads with {lanes} lanes: {what} per lane count, give one road")
    return rows, lanes[0]


def road_lanes(data: Demonstrations, rows: np.ndarray) -> list[int]:
    """Sorted lane counts of the roads (registered scenarios) of the episodes of ``rows``."""
    names = np.unique(data.episodes["scenario"][np.unique(data.episode[rows])])
    try:
        return sorted({get_scenario(str(name)).lanes for name in names})
    except ScenarioError as exc:
        raise DatasetError("demonstrations of a scenario whose road is unknown, so the weights could not name their lane count: "
                           f"{exc}") from None


def data_record(data: Demonstrations, held: Demonstrations, val_rows: np.ndarray) -> dict[str, Any]:
    """What a checkpoint records of its data: fingerprints (independent of the file order) of the training
    demonstrations and of the held-out episodes of ``held`` (those with rows in ``val_rows``), and their count."""
    episodes = np.unique(held.episode[val_rows])
    return {"train": data.fingerprint(), "validation": held.fingerprint(episodes), "validation_episodes": len(episodes)}


@dataclasses.dataclass(frozen=True)
class Split:
    """The demonstrations a training learns from and holds out, and the rows of each, in canonical order."""

    data: Demonstrations  # the training demonstrations
    held: Demonstrations  # the validation demonstrations: ``data`` itself unless separate files were given
    train_rows: np.ndarray  # (N,) row indices into data
    val_rows: np.ndarray  # (V,) row indices into held

    def record(self) -> dict[str, Any]:
        """:func:`data_record` of this split: what its checkpoints record and a resumed run must match."""
        return data_record(self.data, self.held, self.val_rows)

    def lanes(self) -> list[int]:
        """Lane counts of the training roads (checkpoints record them; the planner checks them)."""
        return road_lanes(self.data, self.train_rows)

    def row_counts(self) -> dict[str, int]:
        return {"train": len(self.train_rows), "validation": len(self.val_rows)}


def load_split(data_paths: Paths, validation_paths: Paths | None, tcfg: BaseTrainConfig) -> Split:
    """The rows to learn from and to hold out (see the module docstring); DatasetError when the validation files are
    the training ones or fewer than two training rows remain."""
    data = load_demonstrations(data_paths)
    rows = canonical_order(data, training_rows(data, tcfg.crash_margin))
    if validation_paths:
        held = load_demonstrations(validation_paths)
        if held.fingerprint() == data.fingerprint() or set(_resolved(validation_paths)) & set(_resolved(data_paths)):
            raise DatasetError("the validation demonstrations must be other files than the training ones")
        train_rows, val_rows = rows, canonical_order(held, training_rows(held, tcfg.crash_margin))
    else:
        held = data
        train_rows, val_rows = split_episodes(data, rows, tcfg.validation_fraction, tcfg.seed)
    if tcfg.train_episodes:  # the validation episodes stay the same whatever the count
        train_rows = train_rows[drawn_episodes(data, train_rows, tcfg.train_episodes, tcfg.seed + 1)]
    if len(train_rows) < 2:
        raise DatasetError(f"only {len(train_rows)} usable training rows in {data_paths}: collect more demonstrations")
    return Split(data, held, train_rows, val_rows)


def describe_paths(paths: Paths) -> str:
    """The files of ``paths`` for a message, comma-separated."""
    return ", ".join(str(p) for p in _as_list(paths))


def _as_list(paths: Paths) -> list[str | Path]:
    return [paths] if isinstance(paths, (str, Path)) else list(paths)


def _resolved(paths: Paths) -> list[Path]:
    return [Path(p).resolve() for p in _as_list(paths)]


# ------------------------------------------------------------------------------------------- batching


def epoch_steps(examples: int, batch_size: int) -> tuple[int, int]:
    """(examples per step, steps per epoch): ``batch_size`` capped at ``examples``, and the whole batches that fit
    (each epoch leaves out the remainder of its permutation)."""
    size = min(batch_size, examples)
    return size, examples // size


def minibatches(epoch_key: jax.Array, examples: int, batch_size: int, steps: int) -> list[np.ndarray]:
    """Row indices of one epoch's ``steps`` minibatches: a permutation of ``examples`` drawn from ``epoch_key``."""
    order = np.asarray(jax.random.permutation(jax.random.fold_in(epoch_key, 0), examples))
    return [order[i * batch_size:(i + 1) * batch_size] for i in range(steps)]


def chunks(arrays: Sequence[np.ndarray], fn: Callable, chunk: int = EVAL_CHUNK) -> list[Any]:
    """``fn`` over fixed-size chunks (at most ``chunk``) of the leading axis of ``arrays`` (the last one padded by
    repeating row 0, so every call has one shape and ``fn`` compiles once), outputs trimmed back to the real rows
    (host numpy)."""
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


def accumulate(sums: dict[str, float], loss: Any, terms: Mapping[str, Any]) -> None:
    """Add one step's ``loss`` and its ``terms`` (those named in ``sums`` besides "loss") to the running ``sums``."""
    sums["loss"] += float(loss)
    for name in sums:
        if name != "loss":
            sums[name] += float(terms[name])


def train_means(sums: Mapping[str, float], steps: int) -> dict[str, float]:
    """The epoch's means of the running ``sums`` over its ``steps``, named ``train_<term>`` as the history records them."""
    return {f"train_{name}": total / steps for name, total in sums.items()}


# ------------------------------------------------------------------------------------------- optimiser


@functools.lru_cache(maxsize=16)  # one object per setting: jitted steps take it as a static argument
def make_optimiser(tcfg: BaseTrainConfig, steps_per_epoch: int, decay_mask: Any = None) -> optax.GradientTransformation:
    """AdamW with ``tcfg``'s rate, multiplied by ``decay_factor`` every ``decay_every`` epochs (staircase), and weight
    decay on the parameters ``decay_mask`` selects (None: all)."""
    schedule = optax.exponential_decay(tcfg.learning_rate, transition_steps=tcfg.decay_every * steps_per_epoch,
                                       decay_rate=tcfg.decay_factor, staircase=True)
    return optax.adamw(schedule, weight_decay=tcfg.weight_decay, mask=decay_mask)


# ------------------------------------------------------------------------------------------- output folder


def check_output_folder(out_dir: str | Path, weights: str) -> Path:
    """``out_dir`` as a Path; before anything is read or written, CheckpointError when it is an existing file (a
    trainer writes last.ckpt, ``weights`` and history.json there) and OutputError when it, or the folder it would be
    made in, cannot take a file (read-only, full: :func:`driveopt.files.check_writable_folder`), so that the first
    checkpoint does not fail after the data are loaded and an epoch has run."""
    out = files.check_output_folder(out_dir, CheckpointError, f"{LAST}, {weights}, {HISTORY}")
    files.check_writable_folder(out, "--out")
    return out


def make_output_folder(out: Path) -> Path:
    return files.make_output_folder(out, CheckpointError, f"{LAST} and {HISTORY}")


# ------------------------------------------------------------------------------------------- resumption


def check_same_data(path: Path, stored: Any, now: dict[str, Any]) -> None:
    """CheckpointError unless the checkpoint's data record ``stored`` equals ``now`` (see :func:`data_record`)."""
    if not isinstance(stored, dict) or "validation" not in stored:
        raise CheckpointError(f"{path} records no validation split (written by an older driveopt, whose split depended "
                              "on the order of the files); use a new --out")
    if stored.get("train") != now["train"]:
        raise CheckpointError(f"{path} was trained on other demonstrations (data {stored.get('train')}, now {now['train']}); "
                              "use a new --out")
    if stored != now:
        raise CheckpointError(f"{path} held out other validation episodes ({stored.get('validation_episodes')} episodes "
                              f"{stored.get('validation')}, now {now['validation_episodes']} episodes {now['validation']}); "
                              "resume with the same validation demonstrations, or use a new --out")


def check_same_settings(path: Path, stored: Any, tcfg: BaseTrainConfig) -> None:
    """CheckpointError unless the recorded settings ``stored`` are ``tcfg``'s, ``epochs`` aside (a run may be extended).
    A setting the checkpoint does not record (added to driveopt after it was written) reads as its default."""
    stored = dict(stored or {})
    defaults = type(tcfg)().record()
    mismatch = {k: (stored.get(k, defaults[k]), v) for k, v in tcfg.record().items()
                if k != "epochs" and stored.get(k, defaults[k]) != v}
    if mismatch:
        raise CheckpointError(f"{path} was trained with other settings {mismatch} (stored, now); use a new --out")


def check_same_run(path: Path, meta: dict[str, Any], tcfg: BaseTrainConfig, data: dict[str, Any],
                   records: Mapping[str, tuple[str, Any]]) -> None:
    """CheckpointError unless the checkpoint ``path`` (its ``meta``) continues this run: for each ``key: (what,
    value)`` of ``records`` the same recorded ``value`` (a configuration, the prior, the projection), the same
    settings (:func:`check_same_settings`) and the same data (:func:`check_same_data`)."""
    for key, (what, value) in records.items():
        if meta.get(key) != json.loads(json.dumps(value)):
            raise CheckpointError(f"{path} was trained with another {what} ({meta.get(key)}, now {value}); use a new --out")
    check_same_settings(path, meta.get("train_config"), tcfg)
    check_same_data(path, meta.get("data"), data)


# ------------------------------------------------------------------------------------------- the epoch loop


@dataclasses.dataclass
class TrainingRun:
    """A training into one output folder: what its checkpoints record, its history and the rank of its best epoch."""

    out: Path
    kind: str  # the checkpoints' kind (CHECKPOINT_KIND of the network's module in driveopt.learned)
    weights_name: str  # file name of the best epoch's weights, e.g. "cvae.ckpt"
    meta: dict[str, Any]  # what every checkpoint records first: configurations, settings, data, rows
    history: list[dict[str, Any]] = dataclasses.field(default_factory=list)  # one record per finished epoch
    resumed: dict[str, Any] = dataclasses.field(default_factory=dict)  # the meta of last.ckpt when resuming
    best: Any = math.inf  # rank of the best epoch so far (lower is better; None: no epoch ranked yet)
    started: float = dataclasses.field(default_factory=time.perf_counter)  # [s] perf_counter when the epochs began

    @property
    def last(self) -> Path:
        return self.out / LAST

    @property
    def weights(self) -> Path:
        return self.out / self.weights_name

    def resume(self, state: dict[str, Any], check: Callable[[Path, dict[str, Any]], None]) -> dict[str, Any]:
        """``state`` (the training state a fresh run starts from, a dict of pytrees), restored from last.ckpt when the
        folder has one and ``check(path, its meta)`` accepts it, with the history it recorded; then the output folder
        is made. CheckpointError when last.ckpt is unreadable, refused or of other shapes."""
        if self.last.exists():
            meta, stored = load_checkpoint(self.last, self.kind)
            check(self.last, meta)
            state = restore(state, {k: stored.get(k) for k in state}, self.last, "the training state",
                            unbounded=("opt_state",))
            self.history, self.resumed = list(meta.get("history", [])), meta
        make_output_folder(self.out)
        return state

    def checkpoint_meta(self, history: list[dict[str, Any]], extra: dict[str, Any]) -> dict[str, Any]:
        """A checkpoint's meta after the epochs of ``history``: the run's meta, the epoch count, the history, ``extra``."""
        return {**self.meta, "epoch": len(history), "history": history, **extra}

    def save_weights(self, state: Any, history: list[dict[str, Any]], extra: dict[str, Any]) -> None:
        save_checkpoint(self.weights, self.kind, state, self.checkpoint_meta(history, extra))

    def save_last(self, state: Any, extra: dict[str, Any]) -> None:
        save_checkpoint(self.last, self.kind, state, self.checkpoint_meta(self.history, extra))

    def write_history(self) -> None:
        files.write_json(self.out / HISTORY, self.history)

    def summary(self, **extra: Any) -> dict[str, Any]:
        """What a trainer returns: epochs and history, ``extra``, row counts, seconds of this call's epochs, the folder
        and the weights file (None while no epoch has written it)."""
        return {"epochs": len(self.history), "history": self.history, **extra, "rows": self.meta["rows"],
                "seconds": time.perf_counter() - self.started, "out": str(self.out),
                "weights": str(self.weights) if self.weights.exists() else None}


class EpochTrainer(abc.ABC):
    """What :func:`run_epochs` asks of one trained thing. A subclass holds the parameters and optimiser state it
    updates and ``key``, the run's random key (``PRNGKey(seed)``)."""

    key: jax.Array
    stopped: bool = False  # True once the trainer was asked to stop after this epoch (tests of resumption)

    def epoch_key(self, epoch: int) -> jax.Array:
        """The random key of epoch ``epoch`` (0-based): its minibatches and draws follow from it alone."""
        return jax.random.fold_in(self.key, epoch + 1)

    @abc.abstractmethod
    def train_epoch(self, epoch: int, show: Callable[[str], None]) -> dict[str, Any] | None:
        """Run epoch ``epoch`` (0-based) and validate: its history record (with ``train_loss``), or None when it
        stopped inside the epoch after saving its progress. ``show`` puts a short status on the progress bar."""

    @abc.abstractmethod
    def rank(self, record: dict[str, Any]) -> Any:
        """How the epoch of ``record`` ranks for the weights file: lower is better; None: not a candidate."""

    @abc.abstractmethod
    def weights_state(self) -> Any:
        """What the weights file holds (what the planner loads)."""

    @abc.abstractmethod
    def training_state(self) -> dict[str, Any]:
        """What last.ckpt holds: everything needed to resume."""

    @abc.abstractmethod
    def describe(self, record: dict[str, Any]) -> str:
        """The progress bar's status after the epoch of ``record``."""

    def best_rank(self, run: TrainingRun) -> Any:
        """The rank of the best epoch of a resumed ``run`` (as its last.ckpt recorded it; a fresh run: inf)."""
        return float(run.resumed.get("best", math.inf))

    def after_ranking(self, epoch: int, record: dict[str, Any]) -> None:
        """Called after the epoch was ranked (and its weights kept when best), before last.ckpt is written."""

    def weights_meta(self, run: TrainingRun) -> dict[str, Any]:
        """What the weights file records besides the run's meta, the epoch and the history."""
        return {}

    def last_meta(self, run: TrainingRun) -> dict[str, Any]:
        """What last.ckpt records besides the run's meta, the epoch and the history."""
        return {"best": run.best}


def check_finite(record: dict[str, Any], epoch: int, tcfg: BaseTrainConfig) -> None:
    """TrainingError when the training loss of epoch ``epoch`` (0-based) is NaN or infinite."""
    if not math.isfinite(record["train_loss"]):
        raise TrainingError(f"training diverged in epoch {epoch + 1} (train loss {record['train_loss']}): "
                            f"lower the learning rate (now {tcfg.learning_rate:g})")


def epoch_bar(done: int, tcfg: BaseTrainConfig, stop_after: int | None, desc: str, progress: bool) -> tqdm:
    """Progress bar over the epochs still to run: from ``done`` (those in the history, on resume) to ``tcfg.epochs``,
    at most ``stop_after`` of them in this call."""
    last = tcfg.epochs if stop_after is None else min(tcfg.epochs, done + stop_after)
    return tqdm(range(done, last), initial=done, total=tcfg.epochs, desc=desc, unit="epoch", disable=not progress)


def run_epochs(run: TrainingRun, trainer: EpochTrainer, tcfg: BaseTrainConfig, *, desc: str, progress: bool,
               stop_after: int | None) -> None:
    """Train ``run`` from its history's length to ``tcfg.epochs`` (at most ``stop_after`` epochs in this call). After
    each epoch: stop on a diverged loss, write the weights file when the epoch ranks best, then last.ckpt and
    history.json. A second training into the same folder is refused while this one runs."""
    with files.lock_output_folder(run.out):  # one training writes into a folder at a time
        run.best = trainer.best_rank(run)
        bar = epoch_bar(len(run.history), tcfg, stop_after, desc, progress)
        run.started = time.perf_counter()
        for epoch in bar:
            record = trainer.train_epoch(epoch, bar.set_postfix_str)
            if record is None:
                break
            check_finite(record, epoch, tcfg)
            rank = trainer.rank(record)
            if rank is not None and (run.best is None or rank < run.best):
                run.best = rank
                run.save_weights(trainer.weights_state(), [*run.history, record], trainer.weights_meta(run))
            trainer.after_ranking(epoch, record)
            run.history.append(record)
            run.save_last(trainer.training_state(), trainer.last_meta(run))
            run.write_history()
            bar.set_postfix_str(trainer.describe(record))
            if trainer.stopped:
                break
        bar.close()
