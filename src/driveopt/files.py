"""Files: whole-or-absent outputs, strict JSON, one writer per output folder, content digests, and the files shipped
in the package.

Every writer of results, figures, videos or weights goes through :func:`atomic_write` or :func:`atomic_output` (a
temporary sibling with the same suffix, fsynced, then renamed over the target), so an output is either whole or
absent: an interrupted or failed write (a full disk, a folder that cannot be written) leaves the previous file as it
was, and is reported as an :class:`OutputError` naming the path in one line. JSON goes through :func:`json_text`,
which writes no NaN or Infinity (strict parsers reject them): a missing number is ``null``. Paths are checked with
:func:`check_output_file` before the long work that produces them. A long job holds :func:`output_lock` on its
output folder (or file) for the whole run, so two runs never interleave their writes there. Digests name the
weights a result used.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

from driveopt.errors import DriveoptError

try:
    import fcntl
except ImportError:  # pragma: no cover - no flock (Windows): runs are not guarded against each other
    fcntl = None

LOCK_NAME = ".lock"  # the lock file a job holds in its output folder


class OutputError(DriveoptError, OSError):
    """An output cannot be written: a path that is a folder or has the wrong extension, a folder that cannot be
    written, a full disk. It is also an ``OSError``, so callers that caught failed writes keep catching them."""


class OutputInUseError(OutputError):
    """Another run holds the output folder (or file): two writers would interleave their records."""


def _reason(exc: OSError) -> str:
    return exc.strerror or str(exc) or type(exc).__name__


@contextlib.contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """A temporary sibling of ``path`` (:func:`temporary_sibling`) for the body of the ``with`` to write; renamed over
    ``path`` once written and fsynced (:func:`commit`), removed when the body raises. A failed write (OSError) is an
    :class:`OutputError` naming ``path``."""
    path = Path(path)
    tmp = temporary_sibling(path)
    try:
        yield tmp
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OutputError):
            raise
        raise OutputError(f"cannot write {path}: {_reason(exc)}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    commit(tmp, path)


def temporary_sibling(path: str | Path) -> Path:
    """A new empty file in the folder of ``path`` (created with its parents), hidden, named after ``path`` and with
    its suffix (writers that choose a format by extension pick the same one); OutputError when it cannot be made."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=f".tmp{path.suffix}")
        os.close(fd)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {_reason(exc)}") from None
    return Path(name)


def commit(tmp: str | Path, path: str | Path) -> Path:
    """Flush the written ``tmp`` to the disk, make it readable by all (mkstemp makes it owner-only) and rename it to
    ``path``; when that fails, ``tmp`` is removed and OutputError names ``path``."""
    tmp, path = Path(tmp), Path(path)
    try:
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"cannot write {path}: {_reason(exc)}") from None
    return path


def atomic_write(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` whole or not at all (see :func:`atomic_output`); OutputError when it fails."""
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        f.write(data)
    return Path(path)


def finite_or_none(data: Any) -> Any:
    """``data`` with every float that is not finite replaced by None (JSON's null) and numpy scalars and arrays,
    tuples and sets turned into Python numbers and lists: JSON has no NaN or Infinity, and a number that is missing
    (the plan time of a planner that never plans) is null."""
    if isinstance(data, Mapping):
        return {key: finite_or_none(value) for key, value in data.items()}
    if isinstance(data, (list, tuple, set, frozenset)):
        return [finite_or_none(value) for value in data]
    if hasattr(data, "tolist") and callable(data.tolist):  # numpy arrays and scalars
        return finite_or_none(data.tolist())
    if isinstance(data, float) and not math.isfinite(data):
        return None
    return data


def json_text(data: Any, indent: int | None = 1) -> str:
    """``data`` as strict JSON (see :func:`finite_or_none`); ``indent`` None writes one line."""
    separators = (",", ":") if indent is None else None
    return json.dumps(finite_or_none(data), indent=indent, separators=separators, allow_nan=False)


def write_json(path: str | Path, data: Any, indent: int | None = 1) -> Path:
    """Write ``data`` as strict JSON (:func:`json_text`) to ``path``, whole or not at all (:func:`atomic_write`)."""
    return atomic_write(path, (json_text(data, indent) + "\n").encode())


def refuse_constant(name: str) -> Any:
    """``parse_constant`` of ``json.loads`` for strict JSON: NaN, Infinity and -Infinity are not JSON."""
    raise ValueError(f"{name} is not a JSON value")


def check_output_file(path: str | Path, what: str, suffixes: Sequence[str] = ()) -> Path:
    """Refuse, before any long work, an output path that cannot take the file: a folder, an extension not in
    ``suffixes`` (when given, lower case with the dot), something that is not a regular file (a device), a folder
    that cannot be written (``/proc``, read-only, full). ``what`` names the option in the one-line OutputError."""
    target = Path(path)
    if target.is_dir():
        raise OutputError(f"{what} {path} is a directory; give a file path")
    if suffixes and target.suffix.lower() not in suffixes:
        given = f"'{target.suffix}'" if target.suffix else "no extension"
        raise OutputError(f"{what} {path}: expected a file ending in {', '.join(suffixes)}, got {given}")
    if target.exists() and not target.is_file():
        raise OutputError(f"{what} {path} is not a regular file; give a file path")
    if target.exists() and not os.access(target, os.W_OK):
        raise OutputError(f"{what} {path} cannot be written (permission denied)")
    _probe_nearest_folder(target.parent, f"{what} {path}")
    return target


def check_writable_folder(path: str | Path, what: str) -> Path:
    """Refuse, before any long work, an output folder that cannot take files: an existing file or a path under one,
    or a folder (the nearest that exists, where the missing ones would be made) that cannot be written (``/proc``,
    read-only, full). ``what`` names the option in the one-line OutputError."""
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise OutputError(f"{what} {path} is an existing file; give a folder")
    _probe_nearest_folder(target, f"{what} {path}")
    return target


def _probe_nearest_folder(folder: Path, label: str) -> None:
    """:func:`_probe_folder` on ``folder`` or, while it does not exist, the nearest folder above it that does (where
    it would be created); OutputError naming ``label`` when that is not a folder."""
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise OutputError(f"{label} cannot be written ({folder} is not a folder)")
    _probe_folder(folder, label)


def _probe_folder(folder: Path, what: str) -> None:
    """Create and remove a file in ``folder``: the one check that also holds for root, ``/proc`` and full disks."""
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".probe.") as probe:
            probe.write(b"x")
            probe.flush()
            os.fsync(probe.fileno())
    except OSError as exc:
        raise OutputError(f"{what} cannot be written (folder {folder}: {_reason(exc)})") from None


@contextlib.contextmanager
def output_lock(lock_path: str | Path, what: str) -> Iterator[None]:
    """Hold an exclusive lock on ``lock_path`` (created if missing) for the ``with``; :class:`OutputInUseError`
    (with the holder's PID) at once when another process holds it. The kernel releases the lock when the process
    ends, however it ends, so a killed run never leaves it held. ``what`` names the output in the message."""
    lock_path = Path(lock_path)
    try:
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise OutputError(f"cannot lock {what}: {lock_path}: {_reason(exc)}") from None
    try:
        _take_lock(fd, lock_path, what)
        yield
    finally:
        os.close(fd)  # releases the lock


def _take_lock(fd: int, lock_path: Path, what: str) -> None:
    if fcntl is None:  # pragma: no cover
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        pid = _holder_pid(fd)
        holder = f" (PID {pid})" if pid else ""
        raise OutputInUseError(f"{what} is in use by another run{holder}; wait for it to end or choose another output") from None
    except OSError as exc:
        raise OutputError(f"cannot lock {what}: {lock_path}: {_reason(exc)}") from None
    with contextlib.suppress(OSError):  # the PID is only for the message of the next run: a full disk may keep it out
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)


def _holder_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode("ascii").strip()
    except (OSError, UnicodeDecodeError):
        return None
    return int(text) if text.isdigit() else None


def lock_output_folder(folder: str | Path) -> contextlib.AbstractContextManager[None]:
    """:func:`output_lock` on ``folder/.lock``: one run at a time writes into ``folder`` (which must exist)."""
    return output_lock(Path(folder) / LOCK_NAME, f"the output folder {folder}")


def lock_output_file(path: str | Path) -> contextlib.AbstractContextManager[None]:
    """:func:`output_lock` on a hidden sibling ``.NAME.lock`` of ``path`` (whose folder must exist): one run at a time
    appends to ``path``. The file itself is not locked: the libraries that write it (HDF5) lock it themselves."""
    path = Path(path)
    return output_lock(path.parent / f".{path.name}.lock", f"the output file {path}")


def file_digest(path: str | Path) -> str:
    """The first 16 hex digits of the SHA-256 of a file: how results and checkpoints name the weights they used."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def json_digest(data: Any) -> str:
    """The first 16 hex digits of the SHA-256 of ``data`` as compact JSON with sorted keys (finite numbers only)."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def pytree_digest(tree: Any) -> str:
    """The first 16 hex digits of the SHA-256 over the shapes, dtypes and bytes of a pytree's array leaves (loaded
    weights), in leaf order."""
    import jax
    import numpy as np

    sha = hashlib.sha256()
    for leaf in jax.tree_util.tree_leaves(tree):
        array = np.asarray(leaf)
        sha.update(f"{array.shape}{array.dtype}".encode())
        sha.update(np.ascontiguousarray(array).tobytes())
    return sha.hexdigest()[:16]


def check_output_folder(out: str | Path, error: type[Exception], holds: str) -> Path:
    """``out`` as a Path; ``error`` when it is an existing file (the job writes ``holds`` there)."""
    path = Path(out)
    if path.exists() and not path.is_dir():
        raise error(f"the output folder {path} is an existing file; give a folder (for {holds})")
    return path


def make_output_folder(out: str | Path, error: type[Exception], holds: str) -> Path:
    """Create ``out`` (and its parents) after :func:`check_output_folder`; ``error`` when it cannot be created."""
    path = check_output_folder(out, error, holds)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise error(f"cannot create the output folder {path}: {exc.strerror or exc}") from None
    return path


def shipped_weights_file(by_lanes: dict[int, str], lanes: int) -> Path | None:
    """The file that ``by_lanes`` names for roads with ``lanes`` lanes in ``driveopt/weights``, or None when it names
    none or the file does not ship."""
    name = by_lanes.get(int(lanes))
    if name is None:
        return None
    path = Path(str(resources.files("driveopt") / "weights" / name))
    return path if path.is_file() else None
