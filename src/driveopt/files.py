"""Files: atomic writes, content digests, output folders of the long jobs, and the files shipped in the package.

Every writer of results or weights goes through :func:`atomic_write` (a temporary file in the same folder, fsynced,
then renamed), so an interrupted write leaves the previous file intact. Digests name the weights a result used.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from importlib import resources
from pathlib import Path
from typing import Any


def atomic_write(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder, fsynced, renamed)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)  # mkstemp makes it owner-only
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def file_digest(path: str | Path) -> str:
    """The first 16 hex digits of the SHA-256 of a file: how results and checkpoints name the weights they used."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


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
