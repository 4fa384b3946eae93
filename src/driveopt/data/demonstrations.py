"""Expert demonstrations on disk: an appendable HDF5 file with a schema version.

One row per planning step of an expert episode; one entry per episode in ``episodes/``. Row
datasets (n = rows, K = nodes)::

    observation (n, 55) f4   the planner's input (driveopt.observation)
    init_x      (n, 3)  f4   [m, m/s, m/s^2] x, x', x'' at t = 0 (planning frame: x = 0)
    init_y      (n, 3)  f4   [m, m/s, m/s^2] y, y', y'' at t = 0 (road frame)
    lane_bounds (n, 2)  f4   [m] (y_lb, y_ub) of the ego centre
    setpoints   (n, 8)  f4   chosen set-points (v_1..v_4 [m/s], y_1..y_4 [m])
    coeffs      (n, 2n_c) f4 chosen Bernstein coefficients (x then y)
    trajectory  (n, K, 2) f4 [m] executed plan (x relative to the ego, y road frame) at the nodes
    status      (n,)    i1   PlanStatus of the step (0 = SUCCESS)
    time        (n,)    f4   [s] simulated time of the step
    episode     (n,)    i4   index into episodes/

    episodes/scenario (str), seed, episode, env_seed, collided, duration [s], first_row, num_rows

Schema version 2 adds the expert's **modes** per row (M = ``max_modes``, 8 by default; the distinct
feasible plans of the expert's first and final batches, lowest cost first; the selection rule is in
:mod:`driveopt.data.modes`)::

    mode_setpoints (n, M, 8)   f4  their set-points
    mode_coeffs    (n, M, 2n_c) f4 their projected coefficients (planning frame, like ``coeffs``)
    mode_cost      (n, M)      f4  weighted driving cost
    mode_residual  (n, M)      f4  total constraint residual
    mode_mask      (n, M)      b1  True for a real mode; padding (zeros) after the real ones

A mode's trajectory is ``W @ c`` with the basis of the file's ``num_nodes`` and ``horizon``.

Versions: this driveopt writes version 2 and reads versions 1 and 2. A version-1 file (no modes)
reads as rows without modes (``Demonstrations.modes`` is None, or all masked where files of both
versions are read together), and an episode without modes has the same identity (and fingerprint)
as before, so CVAE checkpoints of version-1 data still resume. Appending to a version-1 file is
refused: collect into a new file.

Episodes are the unit of writing: an episode's rows and its entry are appended together, with the
file opened for that write only, so an interrupted collection loses at most the episodes in flight
and the file can be read between writes. The rows go first, then the entry field by field. An entry
is complete when every field has it and its ``first_row`` / ``num_rows`` cover exactly the rows whose
``episode`` is its index; reading uses complete entries only, and reopening for writing truncates a
partly written entry and every row after the last complete one (a write cut short), so a rerun
redoes that episode.

An episode is identified by (scenario, seed, episode) and a digest of its rows
(:meth:`Demonstrations.episode_ids`): the same episode gives the same identity in any file and at
any position, so fingerprints and orders built on it do not depend on the order of the files.

Integrity: the writer stores with each episode a SHA-256 of its entry and of every stored byte of its
rows (``episodes/checksum``, 64 hex digits, written before the entry's position fields), and reading
verifies it, so a damaged file (a block of zeros, a flipped bit) is refused as corrupted instead of
training on wrong rows; damage to HDF5's own structures makes the read fail, also reported as corrupted.
Files written before driveopt stored checksums (no ``episodes/checksum``) are read unchecked, as before;
so are episodes appended to them. A truncated file is reported as corrupted at once (HDF5 compares the
file's length with the one it recorded). The file keeps HDF5's default (earliest) format: the newer
formats mark a file open for writing in its superblock, and a collector killed mid-write would leave it
unreadable until ``h5clear``.

A write that fails (a full disk, a quota, an I/O error; also Ctrl-C during the write) leaves the file as it was
before it, byte for byte, or removes the file when that write created it (:func:`_writing`): HDF5 rewrites its
metadata in place, so a write cut short there would otherwise leave a file that HDF5 refuses to open and no rerun
could resume. The failure is a DatasetError of one line naming the file and the reason.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import itertools
import json
import os
import time
from pathlib import Path
from typing import Any, Iterable, NamedTuple

import numpy as np

from driveopt.errors import DriveoptError

try:
    import fcntl
except ImportError:  # pragma: no cover - no flock (Windows): readers and the writer are not kept apart
    fcntl = None

FORMAT = "driveopt-demonstrations"
SCHEMA_VERSION = 2  # written
READABLE_VERSIONS = (1, 2)
MAX_MODES = 8  # [-] default M: modes stored per row (``driveopt collect --modes``)
ROW_FIELDS = ("observation", "init_x", "init_y", "lane_bounds", "setpoints", "coeffs", "trajectory", "status", "time")
MODE_FIELDS = ("mode_setpoints", "mode_coeffs", "mode_cost", "mode_residual", "mode_mask")  # version 2
EPISODE_FIELDS = ("scenario", "seed", "episode", "env_seed", "collided", "duration", "first_row", "num_rows")
_POSITION_FIELDS = ("first_row", "num_rows")  # of EPISODE_FIELDS: set by the writer, last
CHECKSUM = "checksum"  # episodes/checksum: SHA-256 (hex) of each episode's entry and rows (absent in older files)
_CHECKSUM_DTYPE = "S64"
_ROW_DTYPES = {"status": np.int8, "mode_mask": np.bool_}
_EPISODE_DTYPES = {"seed": np.int64, "episode": np.int32, "env_seed": np.int64, "collided": np.bool_,
                   "duration": np.float32, "first_row": np.int64, "num_rows": np.int64}


class DatasetError(DriveoptError):
    """A demonstrations file is missing, corrupted, of another schema, or does not match the request."""


def _h5py():
    import h5py

    return h5py


class EpisodeKey(NamedTuple):
    scenario: str
    seed: int
    episode: int


class ModeRows(NamedTuple):
    """The modes of n rows (schema version 2; see the module docstring)."""

    setpoints: np.ndarray  # (n, M, 8)
    coeffs: np.ndarray  # (n, M, 2n_c)
    cost: np.ndarray  # (n, M)
    residual: np.ndarray  # (n, M)
    mask: np.ndarray  # (n, M) bool

    def counts(self) -> np.ndarray:
        """(n,) modes per row."""
        return np.sum(self.mask, axis=1)


class Demonstrations(NamedTuple):
    """All rows of one or more files, as numpy arrays (see the module docstring), plus episode tables."""

    observation: np.ndarray
    init_x: np.ndarray
    init_y: np.ndarray
    lane_bounds: np.ndarray
    setpoints: np.ndarray
    coeffs: np.ndarray
    trajectory: np.ndarray
    status: np.ndarray
    time: np.ndarray
    episode: np.ndarray  # (n,) global episode index into ``episodes``
    episodes: dict[str, np.ndarray]  # EPISODE_FIELDS -> (E,)
    attrs: dict[str, Any]
    modes: ModeRows | None = None  # None when no file has modes (schema version 1)

    def __len__(self) -> int:
        return int(self.observation.shape[0])

    def time_to_crash(self) -> np.ndarray:
        """(n,) [s] until the episode's collision; inf for rows of collision-free episodes."""
        collided = self.episodes["collided"][self.episode]
        end = self.episodes["duration"][self.episode]
        return np.where(collided, end - self.time, np.inf)

    def episode_ids(self) -> list[tuple[str, int, int, str]]:
        """(E,) per episode: (scenario, seed, episode, sha256 of its rows), whatever file or position it has.

        The digest covers the version-1 fields, then the real modes (not the padding), so an episode
        without modes has the same identity as in a version-1 file, whatever M is."""
        order = np.argsort(self.episode, kind="stable")
        bounds = np.searchsorted(self.episode[order], np.arange(len(self.episodes["num_rows"]) + 1))
        ids = []
        for index, (lo, hi) in enumerate(itertools.pairwise(bounds)):
            digest = hashlib.sha256()
            for name in ROW_FIELDS:
                digest.update(np.ascontiguousarray(getattr(self, name)[order[lo:hi]]).tobytes())
            if self.modes is not None:
                mask = self.modes.mask[order[lo:hi]]
                for values in self.modes[:4]:
                    digest.update(np.ascontiguousarray(values[order[lo:hi]][mask]).tobytes())
            ids.append((str(self.episodes["scenario"][index]), int(self.episodes["seed"][index]),
                        int(self.episodes["episode"][index]), digest.hexdigest()))
        return ids

    def episode_rank(self) -> np.ndarray:
        """(E,) each episode's position when sorted by :meth:`episode_ids` (file order does not change it)."""
        ids = self.episode_ids()
        rank = np.empty(len(ids), np.int64)
        rank[sorted(range(len(ids)), key=ids.__getitem__)] = np.arange(len(ids))
        return rank

    def fingerprint(self, episodes: Iterable[int] | None = None) -> str:
        """16 hex digits identifying the content of ``episodes`` (indices into ``episodes``; default: all),
        the same for the same episodes in any file order: a checkpoint records it for its data and split."""
        ids = self.episode_ids()
        chosen = range(len(ids)) if episodes is None else episodes
        text = ";".join(sorted("/".join(map(str, ids[int(e)])) for e in chosen))
        return hashlib.sha256(text.encode()).hexdigest()[:16]


class DemonstrationWriter:
    """Appends episodes to an HDF5 file (created with ``attrs`` if new; schema version 2 with
    ``max_modes`` mode slots per row).

    The file is opened only for each write and closed after it, so between episodes it is complete
    on disk and other processes (``train``, ``load_demonstrations``) can read it.
    """

    def __init__(self, path: str | Path, attrs: dict[str, Any], num_nodes: int, num_coeffs: int, observation_dim: int,
                 max_modes: int = MAX_MODES):
        self.path = Path(path)
        self.max_modes = int(max_modes)
        if self.path.is_dir():
            raise DatasetError(f"{self.path} is a directory; give the demonstrations file's path (e.g. {self.path / 'demonstrations.h5'})")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DatasetError(f"cannot create the folder of {self.path}: {exc.strerror or exc}") from None
        with self._open() as f:
            if "episodes" not in f:
                _create(f, attrs, num_nodes, num_coeffs, observation_dim, self.max_modes)
                return
            _check_attrs(f, self.path, writing=True)
            if f["mode_mask"].shape[1] != self.max_modes:
                raise DatasetError(f"{self.path} stores {f['mode_mask'].shape[1]} modes per row, not {self.max_modes}; use another file")
            mismatch = {k: (f.attrs.get(k), v) for k, v in attrs.items() if _attr(f.attrs.get(k)) != v}
            if mismatch:
                raise DatasetError(f"{self.path} was collected with other settings {mismatch} (stored, requested); use another file")
            _truncate_partial(f)

    @contextlib.contextmanager
    def _open(self):
        """The file open for one write (:func:`_writing`), created when missing; DatasetError when it cannot be
        opened (held longer than LOCK_WAIT_S, corrupted) or a write fails (the file is then left as it was)."""
        try:
            with _writing(self.path) as f:
                yield f
        except _OpenError as exc:
            cause = exc.__cause__
            raise DatasetError(f"cannot open demonstrations {self.path}{_unreadable_hint(cause)}: {cause}") from None

    def done(self) -> set[EpisodeKey]:
        with self._open() as f:
            eps = f["episodes"]
            scen = [s.decode() if isinstance(s, bytes) else str(s) for s in eps["scenario"][:]]
            return {EpisodeKey(s, int(a), int(b)) for s, a, b in zip(scen, eps["seed"][:], eps["episode"][:])}

    def append_episode(self, episode: dict[str, Any], rows: dict[str, np.ndarray]) -> None:
        """Append one episode: ``episode`` has EPISODE_FIELDS but first_row/num_rows; ``rows`` ROW_FIELDS and
        optionally MODE_FIELDS (all or none: without them the rows have no modes).

        Everything is checked before the first byte is written; a write cut short before is removed first."""
        with self._open() as f:
            index, start = _truncate_partial(f)
            data = _checked_rows(f, rows)
            n = int(data["observation"].shape[0])
            entry = {**{name: episode[name] for name in EPISODE_FIELDS if name not in _POSITION_FIELDS},
                     "first_row": start, "num_rows": n}
            data["episode"] = np.full(n, index, np.int32)
            for name in (*ROW_FIELDS, "episode", *MODE_FIELDS):
                _write_from(f[name], start, data[name])
            fields = list(EPISODE_FIELDS)
            if CHECKSUM in f["episodes"]:  # before the position fields, so that a complete entry has it
                entry[CHECKSUM] = episode_checksum(entry, data)
                fields.insert(EPISODE_FIELDS.index(_POSITION_FIELDS[0]), CHECKSUM)
            for name in fields:  # the entry goes last: it marks the rows complete
                ds = f["episodes"][name]
                ds.resize(index + 1, axis=0)
                ds[index] = entry[name]


def _create(f: Any, attrs: dict[str, Any], num_nodes: int, num_coeffs: int, observation_dim: int, max_modes: int) -> None:
    f.attrs["format"] = FORMAT
    f.attrs["schema_version"] = SCHEMA_VERSION
    for k, v in attrs.items():
        f.attrs[k] = v
    shapes = {"observation": (observation_dim,), "init_x": (3,), "init_y": (3,), "lane_bounds": (2,),
              "setpoints": (8,), "coeffs": (num_coeffs,), "trajectory": (num_nodes, 2), "status": (), "time": (),
              "mode_setpoints": (max_modes, 8), "mode_coeffs": (max_modes, num_coeffs), "mode_cost": (max_modes,),
              "mode_residual": (max_modes,), "mode_mask": (max_modes,)}
    for name in (*ROW_FIELDS, *MODE_FIELDS):
        f.create_dataset(name, shape=(0, *shapes[name]), maxshape=(None, *shapes[name]),
                         dtype=_ROW_DTYPES.get(name, np.float32), chunks=(256, *shapes[name]))
    f.create_dataset("episode", shape=(0,), maxshape=(None,), dtype=np.int32, chunks=(256,))
    group = f.create_group("episodes")
    for name in EPISODE_FIELDS:
        dtype = _h5py().string_dtype() if name == "scenario" else _EPISODE_DTYPES[name]
        group.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(64,))
    group.create_dataset(CHECKSUM, shape=(0,), maxshape=(None,), dtype=_CHECKSUM_DTYPE, chunks=(64,))


def _checked_rows(f: Any, rows: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``rows`` as arrays of the file's dtypes (no modes: padding) after checking that every field has the same row
    count and the file's row shape (the checksum is taken of exactly the values written)."""
    data = {name: np.asarray(rows[name]) for name in ROW_FIELDS}
    n = data["observation"].shape[0]
    given = [name for name in MODE_FIELDS if name in rows]
    if given and len(given) != len(MODE_FIELDS):
        raise DatasetError(f"episode rows give only some mode fields {given}; give all of {list(MODE_FIELDS)} or none")
    for name in MODE_FIELDS:
        data[name] = np.asarray(rows[name]) if given else np.zeros((n, *f[name].shape[1:]), f[name].dtype)
    for name, values in data.items():
        if values.shape[:1] != (n,) or values.shape[1:] != f[name].shape[1:]:
            raise DatasetError(f"episode rows '{name}' have shape {values.shape}, expected ({n}, {f[name].shape[1:]})")
    if given and not np.all(np.isfinite(data["mode_cost"][data["mode_mask"].astype(bool)])):
        raise DatasetError("episode rows have a mode with a non-finite cost")
    return {name: np.ascontiguousarray(values, dtype=f[name].dtype) for name, values in data.items()}


def episode_checksum(entry: dict[str, Any], rows: dict[str, np.ndarray]) -> bytes:
    """SHA-256 (64 hex digits, as bytes) of an episode's entry (EPISODE_FIELDS in the file's dtypes) and of its
    rows (name -> array in the file's dtype), in a fixed order: what the writer stores and the reader recomputes."""
    digest = hashlib.sha256()
    for name in EPISODE_FIELDS:
        value = entry[name]
        if name == "scenario":
            digest.update((value.decode() if isinstance(value, bytes) else str(value)).encode())
        else:
            digest.update(np.asarray(value, _EPISODE_DTYPES[name]).tobytes())
    for name in sorted(rows):
        digest.update(name.encode())
        digest.update(np.ascontiguousarray(rows[name]).tobytes())
    return digest.hexdigest().encode()


def _row_datasets(f: Any) -> tuple[str, ...]:
    """Names of the per-row datasets of an open file (the mode fields only in version 2)."""
    return (*ROW_FIELDS, "episode", *(name for name in MODE_FIELDS if name in f))


def _write_from(dataset: Any, start: int, values: np.ndarray) -> None:
    """Resize ``dataset`` to end with ``values`` written from row ``start``."""
    dataset.resize(start + len(values), axis=0)
    dataset[start:] = values


def _complete_extent(f: Any) -> tuple[int, int]:
    """(complete episode entries, rows they cover): see the module docstring for what is complete."""
    eps = f["episodes"]
    count = min(eps[name].shape[0] for name in EPISODE_FIELDS)
    if count and not _entry_matches_rows(f, count - 1):
        count -= 1  # only the last entry can be torn: appends are sequential
    end = int(eps["first_row"][count - 1] + eps["num_rows"][count - 1]) if count else 0
    return count, end


def _entry_matches_rows(f: Any, index: int) -> bool:
    """Whether entry ``index`` starts where the previous one ends and covers exactly the rows labelled ``index``."""
    eps = f["episodes"]
    first, num = int(eps["first_row"][index]), int(eps["num_rows"][index])
    expected = int(eps["first_row"][index - 1] + eps["num_rows"][index - 1]) if index else 0
    available = min(f[name].shape[0] for name in _row_datasets(f))
    if first != expected or num < 0 or first + num > available:
        return False
    labels = f["episode"][first:min(first + num + 1, available)]
    return bool(np.all(labels[:num] == index)) and not np.any(labels[num:] == index)


def _truncate_partial(f: Any) -> tuple[int, int]:
    """Drop a partly written episode entry and the rows beyond the last complete episode (an append cut
    short); returns (complete episodes, their rows): where the next episode goes."""
    count, end = _complete_extent(f)
    for name in (*EPISODE_FIELDS, *((CHECKSUM,) if CHECKSUM in f["episodes"] else ())):
        if f["episodes"][name].shape[0] > count:
            f["episodes"][name].resize(count, axis=0)
    for name in _row_datasets(f):
        if f[name].shape[0] != end:
            f[name].resize(end, axis=0)
    return count, end


LOCK_WAIT_S = 60.0
"""How long [s] opening a demonstrations file waits for another process (a reader or the collector) to close it."""


def _is_lock_error(exc: BaseException) -> bool:
    """Whether opening failed because another process holds HDF5's file lock: errno EAGAIN / EWOULDBLOCK, or HDF5's
    words for it (not merely "lock" anywhere: a truncated file's message names "sblock", the superblock)."""
    if isinstance(exc, OSError) and exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
        return True
    return "unable to lock file" in str(exc).lower()


def _open_waiting_for_lock(path: Path, mode: str) -> Any:
    """``h5py.File(path, mode)``, retried while another process holds the file's HDF5 lock (the collector opens the
    file only for each write and readers only for each load, so a lock is released within about a second); the last
    OSError after LOCK_WAIT_S seconds, or at once when the error is not a lock (a truncated or corrupted file)."""
    deadline = time.monotonic() + LOCK_WAIT_S
    delay = 0.05
    while True:
        try:
            return _h5py().File(path, mode)
        except OSError as exc:
            if not _is_lock_error(exc) or time.monotonic() + delay > deadline:
                raise
        time.sleep(delay)
        delay = min(2 * delay, 1.0)


class _OpenError(Exception):
    """Opening the file for a write failed (held by another process, corrupted); ``__cause__`` is the OSError."""


class _JournaledFile:
    """The demonstrations file as h5py's ``fileobj`` driver writes it during one write, kept undoable.

    Before a write replaces bytes the file held when opened, those bytes are kept, so :meth:`undo` restores the file
    exactly: cut back to its former length, the replaced bytes written back (HDF5 rewrites its metadata in place, so
    a write cut short by a full disk would otherwise leave a file HDF5 cannot open). After the first write that fails
    the rest are dropped unwritten while HDF5 carries on, so HDF5 closes the file without errors of its own and the
    failure (:attr:`failure`) is reported once, by the caller."""

    def __init__(self, path: Path, fd: int, created: bool):
        self.path, self.created = path, created
        self._fd = fd
        self.length = os.fstat(fd).st_size  # [bytes] when opened: what undo restores
        self._pos = 0
        self._kept: list[tuple[int, bytes]] = []  # (offset, the bytes a write replaced), in the order written
        self.failure: OSError | None = None
        self._ended = False  # undone or closed: nothing more reaches the disk

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        base = {os.SEEK_SET: 0, os.SEEK_CUR: self._pos, os.SEEK_END: os.fstat(self._fd).st_size}[whence]
        self._pos = base + offset
        return self._pos

    def tell(self) -> int:
        return self._pos

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")
        data = os.pread(self._fd, len(view), self._pos)
        view[:len(data)] = data
        self._pos += len(data)
        return len(data)

    def read(self, size: int = -1) -> bytes:
        if size < 0:
            size = max(os.fstat(self._fd).st_size - self._pos, 0)
        data = os.pread(self._fd, size, self._pos)
        self._pos += len(data)
        return data

    def write(self, data: Any) -> int:
        view = memoryview(data).cast("B")
        if self.failure is None and not self._ended:
            try:
                self._keep(self._pos, len(view))
                done = 0
                while done < len(view):
                    done += os.pwrite(self._fd, view[done:], self._pos + done)
            except OSError as exc:
                self.failure = exc
        self._pos += len(view)
        return len(view)

    def truncate(self, size: int | None = None) -> int:
        size = self._pos if size is None else size
        if self.failure is None and not self._ended:
            try:
                self._keep(size, self.length - size)
                os.ftruncate(self._fd, size)
            except OSError as exc:
                self.failure = exc
        return size

    def flush(self) -> None:
        """Nothing is buffered here: writes go to the descriptor as HDF5 makes them (see :meth:`sync`)."""

    def _keep(self, offset: int, size: int) -> None:
        end = min(offset + size, self.length)
        if offset < end:
            self._kept.append((offset, os.pread(self._fd, end - offset, offset)))

    def sync(self) -> None:
        """Flush the written bytes to the disk (a disk that cannot hold them says so now, not at a later read); the
        failure of a write, or of this flush, is raised as the OSError."""
        if self.failure is None:
            try:
                os.fsync(self._fd)
            except OSError as exc:
                self.failure = exc
        if self.failure is not None:
            raise self.failure

    def undo(self) -> None:
        """The file as it was when opened: removed when this write created it, else cut back to its former length
        (which frees the space the write took) and the replaced bytes written back, latest first. OSError when that
        fails too."""
        self._ended = True
        if self.created:
            self.path.unlink(missing_ok=True)
            return
        os.ftruncate(self._fd, self.length)
        for offset, data in reversed(self._kept):
            done = 0
            while done < len(data):
                done += os.pwrite(self._fd, data[done:], offset + done)
        os.fsync(self._fd)

    def close(self) -> None:
        self._ended = True
        os.close(self._fd)  # releases the lock


def _open_journaled(path: Path) -> _JournaledFile:
    """``path`` opened for one write (created when missing) and locked as HDF5 locks a file open for writing, so
    readers (which take HDF5's shared lock) and this writer exclude each other; the lock is retried while another
    process holds it (:data:`LOCK_WAIT_S`, as :func:`_open_waiting_for_lock`). _OpenError when it cannot be opened
    or locked in time."""
    try:
        try:
            fd, created = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644), True
        except FileExistsError:
            fd, created = os.open(path, os.O_RDWR), False
    except OSError as exc:
        raise _OpenError() from exc
    journal = _JournaledFile(path, fd, created)
    deadline = time.monotonic() + LOCK_WAIT_S
    delay = 0.05
    while fcntl is not None:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except OSError as exc:
            if not _is_lock_error(exc) or time.monotonic() + delay > deadline:
                journal.undo()
                journal.close()
                raise _OpenError() from exc
        time.sleep(delay)
        delay = min(2 * delay, 1.0)
    return journal


@contextlib.contextmanager
def _writing(path: Path):
    """The demonstrations file open for one write (HDF5 through :class:`_JournaledFile`), created when missing, whole
    or not at all: when the body or the write fails (a full disk, Ctrl-C), the file is left as it was before
    (removed when this write created it). A failed write is a DatasetError naming the file and the reason in one
    line; _OpenError when the file cannot be opened (held longer than LOCK_WAIT_S, corrupted); any other exception
    of the body propagates as it was, after the undo."""
    journal = _open_journaled(path)
    try:
        try:
            f = _h5py().File(journal, "w" if journal.length == 0 else "r+")
        except OSError as exc:
            raise _OpenError() from exc
        with f:
            yield f
        journal.sync()
    except BaseException as exc:
        failure = journal.failure
        try:
            journal.undo()
        except OSError as undo_exc:
            if failure is not None:
                raise DatasetError(f"cannot write demonstrations {path}: {_os_reason(failure)}; restoring the file "
                                   f"failed too ({_os_reason(undo_exc)}): it may be damaged") from None
            raise
        if failure is not None:
            kept = ("the file it was creating is removed" if journal.created
                    else "the file is as it was before this write, so a rerun resumes")
            raise DatasetError(f"cannot write demonstrations {path}: {_os_reason(failure)}; {kept} (once there is "
                               "room)") from None
        raise
    finally:
        journal.close()


def _os_reason(exc: OSError) -> str:
    return exc.strerror or str(exc) or type(exc).__name__


def _unreadable_hint(exc: BaseException) -> str:
    """Why an HDF5 file could not be opened or read, for the message: held by another process, or corrupted."""
    if _is_lock_error(exc):
        return f" (another process held it for over {LOCK_WAIT_S:g} s)"
    if "truncated file" in str(exc).lower():
        return " (corrupted: truncated, shorter than HDF5 recorded)"
    return " (corrupted or not HDF5)"


def _attr(value: Any) -> Any:
    return value.item() if isinstance(value, np.generic) else value


def _check_attrs(f: Any, path: Path, writing: bool = False) -> int:
    """The file's schema version; DatasetError unless it is a demonstrations file this driveopt reads
    (or, ``writing``, appends to)."""
    if f.attrs.get("format") != FORMAT:
        raise DatasetError(f"{path} is not a driveopt demonstrations file (format attribute {f.attrs.get('format')!r})")
    version = int(f.attrs.get("schema_version", -1))
    if version not in READABLE_VERSIONS:
        raise DatasetError(f"{path} has schema version {version}; this driveopt reads versions "
                           f"{', '.join(map(str, READABLE_VERSIONS))}")
    if writing and version != SCHEMA_VERSION:
        raise DatasetError(f"{path} has schema version {version} (no modes); this driveopt appends version "
                           f"{SCHEMA_VERSION} only: collect into a new file (version {version} stays readable)")
    return version


def load_demonstrations(paths: str | Path | Iterable[str | Path]) -> Demonstrations:
    """Read and validate one or more files (complete episodes only) into one :class:`Demonstrations`."""
    paths = [Path(paths)] if isinstance(paths, (str, Path)) else [Path(p) for p in paths]
    if not paths:
        raise DatasetError("no demonstrations file given")
    parts = [_load_one(p) for p in paths]
    first = parts[0]
    for other, path in zip(parts[1:], paths[1:]):
        for key in ("num_nodes", "horizon"):
            if first.attrs.get(key) != other.attrs.get(key):
                raise DatasetError(f"{path}: {key} = {other.attrs.get(key)} differs from {paths[0]} ({first.attrs.get(key)})")
    offsets = np.cumsum([0] + [len(p.episodes["num_rows"]) for p in parts[:-1]])
    rows = {name: np.concatenate([getattr(p, name) for p in parts]) for name in ROW_FIELDS}
    episode = np.concatenate([p.episode + off for p, off in zip(parts, offsets)])
    episodes = {name: np.concatenate([p.episodes[name] for p in parts]) for name in EPISODE_FIELDS}
    return Demonstrations(**rows, episode=episode, episodes=episodes, attrs=first.attrs, modes=_joined_modes(parts))


def _joined_modes(parts: list[Demonstrations]) -> ModeRows | None:
    """The modes of all parts, padded to the largest M; rows of a part without modes have none (all masked)."""
    with_modes = [p.modes for p in parts if p.modes is not None]
    if not with_modes:
        return None
    width = max(m.mask.shape[1] for m in with_modes)

    def padded(part: Demonstrations) -> ModeRows:
        n = len(part)
        modes = part.modes
        if modes is None:
            modes = ModeRows(np.zeros((n, 0, 8), np.float32), np.zeros((n, 0, part.coeffs.shape[1]), np.float32),
                             np.zeros((n, 0), np.float32), np.zeros((n, 0), np.float32), np.zeros((n, 0), bool))
        return ModeRows(*(np.pad(a, [(0, 0), (0, width - a.shape[1])] + [(0, 0)] * (a.ndim - 2)) for a in modes))

    return ModeRows(*(np.concatenate(arrays) for arrays in zip(*(padded(p) for p in parts))))


def _load_one(path: Path) -> Demonstrations:
    if not path.exists():
        raise DatasetError(f"demonstrations file {path} does not exist")
    if not path.is_file():
        raise DatasetError(f"demonstrations file {path} is not a regular file")
    try:
        with _open_waiting_for_lock(path, "r") as f:
            version = _check_attrs(f, path)
            count, end = _complete_extent(f)
            eps = {name: f["episodes"][name][:count] for name in EPISODE_FIELDS}
            eps["scenario"] = np.array([s.decode() if isinstance(s, bytes) else str(s) for s in eps["scenario"]])
            rows = {name: f[name][:end] for name in (*ROW_FIELDS, "episode", *(MODE_FIELDS if version >= 2 else ()))}
            checksums = f["episodes"][CHECKSUM][:count] if CHECKSUM in f["episodes"] else np.zeros(0, _CHECKSUM_DTYPE)
            attrs = {k: _attr(v) for k, v in f.attrs.items()}
    except DatasetError:
        raise
    except (OSError, KeyError, ValueError, IndexError) as exc:  # h5py's errors on a damaged file
        raise DatasetError(f"cannot read demonstrations {path}{_unreadable_hint(exc)}: {exc}") from None
    for name, data in rows.items():
        if data.dtype.kind == "f" and not np.all(np.isfinite(data)):
            raise DatasetError(f"{path}: dataset '{name}' contains NaN or inf")
    _verify_checksums(path, eps, rows, checksums)
    if np.any(rows["episode"] >= max(len(eps["num_rows"]), 1)) or np.any(rows["episode"] < 0):
        raise DatasetError(f"{path}: row episode indices out of range")
    modes = None
    if "mode_mask" in rows:
        modes = ModeRows(*(rows[name] for name in MODE_FIELDS[:4]), rows["mode_mask"].astype(bool))
    return Demonstrations(**{n: rows[n] for n in ROW_FIELDS}, episode=rows["episode"].astype(np.int64), episodes=eps,
                          attrs=attrs, modes=modes)


def _verify_checksums(path: Path, eps: dict[str, np.ndarray], rows: dict[str, np.ndarray], checksums: np.ndarray) -> None:
    """DatasetError unless every episode with a stored checksum has the entry and rows it was written with."""
    for index, stored in enumerate(checksums):
        first, num = int(eps["first_row"][index]), int(eps["num_rows"][index])
        entry = {name: eps[name][index] for name in EPISODE_FIELDS}
        if first < 0 or num < 0 or first + num > len(rows["episode"]) or stored != episode_checksum(
                entry, {name: values[first:first + num] for name, values in rows.items()}):
            raise DatasetError(f"demonstrations {path} are corrupted: episode {index} ({entry['scenario']}, seed "
                               f"{entry['seed']}, episode {entry['episode']}) does not match the checksum written with it")


def mode_distribution(counts: Iterable[int]) -> dict[str, int]:
    """{"k": rows with k modes} for every k from 0 to the largest count (JSON-ready keys)."""
    counts = np.asarray(list(counts) if not isinstance(counts, np.ndarray) else counts, np.int64)
    histogram = np.bincount(counts) if counts.size else np.zeros(1, np.int64)
    return {str(k): int(c) for k, c in enumerate(histogram)}


def describe(data: Demonstrations) -> dict[str, Any]:
    """JSON-ready summary: rows, episodes per scenario, collisions, modes per row (None without modes),
    collection settings."""
    scen, counts = np.unique(data.episodes["scenario"], return_counts=True)
    return {
        "rows": len(data),
        "episodes": int(len(data.episodes["num_rows"])),
        "per_scenario": {str(s): int(c) for s, c in zip(scen, counts)},
        "collided_episodes": int(np.sum(data.episodes["collided"])),
        "success_rows": int(np.sum(data.status == 0)),
        "modes_per_row": None if data.modes is None else mode_distribution(data.modes.counts()),
        "attrs": {k: (json.loads(v) if isinstance(v, str) and v.startswith("{") else v) for k, v in data.attrs.items()},
    }
