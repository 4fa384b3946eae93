"""JAX's persistent compilation cache, on by default: a second process that plans the same configuration loads the
compiled planner from disk (about a second) instead of compiling it again (several seconds).

Where it lives: ``$DRIVEOPT_COMPILATION_CACHE`` when that names a folder; otherwise ``$XDG_CACHE_HOME/driveopt/jax``
(``~/.cache/driveopt/jax`` without ``XDG_CACHE_HOME``). ``DRIVEOPT_COMPILATION_CACHE=0`` (or ``off``, ``false``,
``no``) turns it off. A cache folder configured for JAX itself (``JAX_COMPILATION_CACHE_DIR``, or
``jax.config.update("jax_compilation_cache_dir", ...)`` before driveopt is imported) is never replaced, and then
driveopt changes none of JAX's cache settings.

:func:`enable_default` runs when :mod:`driveopt.xla` is imported, that is, before anything of driveopt's is compiled,
in every process that plans (the command line, bench's spawned workers, a user's script). It sets JAX's process-wide
options: computations of the user's own that take at least :data:`MIN_COMPILE_SECONDS` to compile are cached in the
same folder.

Two processes may share the folder: entries are looked up and written under JAX's file lock (on whenever the cache has
a size limit, :data:`MAX_BYTES`), so neither reads an entry the other is half-way through writing, and a key that is
already there is never written again. The least recently used entries go when the folder would exceed the limit.
Anyone who can write to the folder can run code in the processes that read it (JAX's warning): keep it private.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

ENV = "DRIVEOPT_COMPILATION_CACHE"
OFF_VALUES = ("0", "off", "false", "no")
MIN_COMPILE_SECONDS = 0.5  # [s] computations compiled faster than this are not written (JAX's default: 1 s)
MAX_BYTES = 2 * 1024**3  # [bytes] the folder's limit (an entry of the default planner is about 1-3 MB)


class CacheSetupWarning(RuntimeWarning):
    """The cache folder cannot be used (it is a file, or cannot be created): planning goes on, compiling as before."""


def cache_folder(environ: dict[str, str] | None = None) -> Path | None:
    """The folder driveopt caches compilations in, from ``environ`` (default ``os.environ``); None when turned off."""
    env = os.environ if environ is None else environ
    value = env.get(ENV, "").strip()
    if value.lower() in OFF_VALUES:
        return None
    if value and value != "1":
        return Path(value).expanduser()
    base = env.get("XDG_CACHE_HOME", "").strip()
    root = Path(base).expanduser() if base and Path(base).is_absolute() else Path.home() / ".cache"
    return root / "driveopt" / "jax"


def enable_default() -> Path | None:
    """Point JAX's persistent compilation cache at :func:`cache_folder`, unless it is turned off or JAX already has a
    cache folder. Returns the folder JAX caches in (driveopt's, or the one configured before), None when none. A folder
    that cannot be created leaves the cache off with a one-line :class:`CacheSetupWarning`. Calling it again changes
    nothing."""
    import jax

    configured = jax.config.jax_compilation_cache_dir
    if configured:
        return Path(configured)
    folder = cache_folder()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    except OSError as exc:
        return _off(f"cannot create {folder}: {exc.strerror or exc}")
    if not os.access(folder, os.W_OK | os.X_OK):
        return _off(f"cannot write to {folder}")
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)  # every size: no filesystem-based minimum
    if _has_filelock():
        jax.config.update("jax_compilation_cache_max_size", MAX_BYTES)  # which also turns on JAX's file lock
    jax.config.update("jax_compilation_cache_dir", str(folder))
    return folder


def _off(reason: str) -> None:
    warnings.warn(f"compilation cache off ({ENV}=0 silences this): {reason}", CacheSetupWarning, stacklevel=3)


def _has_filelock() -> bool:
    """JAX needs the ``filelock`` package for a size-limited (locked) cache; without it the cache is unlocked."""
    import importlib.util

    return importlib.util.find_spec("filelock") is not None
