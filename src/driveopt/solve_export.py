"""The planner's compiled ``solve``, exported once per graph, so that a later process starts planning without tracing
and lowering it again.

JAX's persistent compilation cache (:mod:`driveopt.compilation_cache`) saves the compilation, but its key is the
lowered program: a second process still traces ``solve`` (about 1 s on two cores) and lowers it to StableHLO (about
1 s) before the cache can answer. Here the lowered program itself is kept (``jax.export``, serialized StableHLO), in
the ``driveopt-solve`` folder inside the compilation cache's folder, one file per graph: a later process reads it
(milliseconds), and compiling it is a hit in the compilation cache.

A graph is named by everything that shapes it: driveopt's source files, the versions of JAX, Flax and numpy, the
backend and numerical settings, the static arguments (configuration and method, by their ``repr``: frozen
dataclasses), the structure of the arguments (pytree types with their static fields) and every argument's shape and
dtype. Values (the problem, network weights, keys) are arguments of the exported program, never part of it. A graph
with an argument or strategy of a type defined outside driveopt and those libraries (a user's own prior, filter, or
ranking inside a method) is never exported: its code could change without changing the name, so it is traced as
usual. A file that
cannot be read or loaded is exported again and replaced; a graph that cannot be exported runs as a plain ``jax.jit``,
with one warning.

The files hold pickled pytree structures: as with JAX's own cache, anyone who can write to the folder can run code in
the processes that read it, so it lives in driveopt's private cache folder. With the compilation cache off
(``DRIVEOPT_COMPILATION_CACHE=0``) nothing is exported or read. The folder keeps at most :data:`MAX_FILES` files
(the least recently used go first).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import os
import pickle
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax

from driveopt.files import atomic_write

FORMAT = 1  # bumped when the file layout changes: older files are then never read
FOLDER = "driveopt-solve"  # inside the compilation cache's folder
MAX_FILES = 64  # [files] one per graph (a configuration at a batch size): about 250 kB each
SUFFIX = ".export"
TRUSTED_MODULES = ("builtins", "collections", "driveopt", "flax", "jax", "jaxlib", "numpy", "optax")


class ExportWarning(RuntimeWarning):
    """A graph could not be exported or its file not written: it runs as a plain ``jax.jit``, compiled as before."""


def export_folder() -> Path | None:
    """Where exported graphs live (inside JAX's compilation cache folder), or None when that cache is off."""
    cache = jax.config.jax_compilation_cache_dir
    return Path(cache) / FOLDER if cache else None


@functools.cache
def source_digest() -> str:
    """SHA-256 of driveopt's Python sources (relative paths and contents): any change of the code changes every key."""
    root = Path(__file__).parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def _type_name(kind: type | Callable[..., Any]) -> str | None:
    """``module.qualname`` of a type or function; None when its module is not one whose code the key covers
    (driveopt, whose sources it digests, and the versioned libraries): a user's own prior or strategy may change
    without a trace here."""
    module = kind.__module__ or ""
    return f"{module}.{kind.__qualname__}" if module.split(".")[0] in TRUSTED_MODULES else None


def _tree_text(tree: Any) -> str | None:
    """Every node of pytree structure ``tree`` as its type and static fields; None when a type is not trusted."""
    if tree.num_nodes == 1 and tree.num_leaves == 1:
        return "*"
    kind, aux = tree.node_data()
    name = _type_name(kind)
    children = [_tree_text(child) for child in tree.children()]
    if name is None or None in children:
        return None
    return f"{name}[{aux!r}]({', '.join(children)})"


def _trusted(value: Any) -> bool:
    """Whether the static argument ``value`` and every value inside it (the fields of a dataclass, the items of a tuple
    or list: a method's strategies) are of types whose code the name covers (:func:`_type_name`)."""
    if _type_name(type(value)) is None:
        return False
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return all(_trusted(getattr(value, f.name)) for f in dataclasses.fields(value))
    if isinstance(value, (tuple, list)):
        return all(_trusted(item) for item in value)
    return True


def graph_key(fun: Callable[..., Any], static: dict[str, Any], in_tree: Any, avals: tuple[Any, ...]) -> str | None:
    """The name of the graph that ``fun`` with ``static`` arguments and arguments of structure ``in_tree`` and abstract
    values ``avals`` (shapes, dtypes and weak types, not values) lowers to; None when ``fun`` or an argument's type
    comes from code the name does not cover (it is then never exported)."""
    tree = _tree_text(in_tree)
    if tree is None or _type_name(fun) is None or not all(map(_trusted, static.values())):
        return None
    versions = {name: getattr(sys.modules[name], "__version__", "") for name in TRUSTED_MODULES if name in sys.modules}
    parts = [
        f"format {FORMAT}", _type_name(fun), source_digest(), repr(sorted(versions.items())),
        jax.default_backend(), f"x64 {jax.config.jax_enable_x64}", f"precision {jax.config.jax_default_matmul_precision}",
        repr(sorted(static.items())), tree, *map(repr, avals),
    ]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:40]


class ExportedCalls:
    """``fun(*args, **kwargs)`` through exported graphs, as ``jax.jit(fun, static_argnames=..., **jit_options)``
    would run it: each graph is loaded from its file, or exported and written, once per process; calls then run its
    jitted executable. ``static_argnames`` are passed by keyword (hashable); ``jit_options``: compiler options."""

    def __init__(self, fun: Callable[..., Any], static_argnames: tuple[str, ...], jit_options: dict[str, Any]) -> None:
        self.fun, self.static_argnames, self.jit_options = fun, static_argnames, jit_options
        self.plain = jax.jit(fun, static_argnames=static_argnames, **jit_options)  # graphs not exported run through it
        self.calls: dict[Any, Callable[..., Any]] = {}  # (static, structure, avals) -> callable of the flat leaves

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        static = {name: value for name, value in kwargs.items() if name in self.static_argnames}
        dynamic = {name: value for name, value in kwargs.items() if name not in self.static_argnames}
        leaves, in_tree = jax.tree_util.tree_flatten((args, dynamic))
        avals = tuple(map(jax.typeof, leaves))
        graph = (tuple(sorted(static.items())), in_tree, avals)
        call = self.calls.get(graph)
        if call is None:
            call = self.calls[graph] = self._load(static, in_tree, avals)
        return call(*leaves)

    def _load(self, static: dict[str, Any], in_tree: Any, avals: tuple[Any, ...]) -> Callable[..., Any]:
        folder = export_folder()
        key = None if folder is None else graph_key(self.fun, static, in_tree, avals)
        if key is None:
            return self._plain(static, in_tree)
        path = folder / f"{key}{SUFFIX}"
        loaded = _read(path)
        if loaded is None:
            made = self._export(static, in_tree, avals)
            if made is None:
                return self._plain(static, in_tree)
            loaded, blob = made
            _write(path, blob)
        exported, out_tree = loaded

        def call(*leaves):
            return exported.call(*leaves)

        call.__name__ = self.fun.__name__  # named as the function in logs and cache files: jit_solve
        run = jax.jit(call, **self.jit_options)
        return lambda *leaves: jax.tree_util.tree_unflatten(out_tree, run(*leaves))

    def _call(self, fun: Callable[..., Any], static: dict[str, Any], in_tree: Any, leaves: Any) -> Any:
        args, dynamic = jax.tree_util.tree_unflatten(in_tree, leaves)
        return fun(*args, **dynamic, **static)

    def _plain(self, static: dict[str, Any], in_tree: Any) -> Callable[..., Any]:
        return lambda *leaves: self._call(self.plain, static, in_tree, leaves)

    def _export(self, static: dict[str, Any], in_tree: Any, avals: tuple[Any, ...]) -> tuple[tuple[Any, Any], bytes] | None:
        """((Exported, output structure), the file's bytes), or None (with a warning) when the graph cannot be exported."""
        out_trees = []

        def flat(*leaves):
            out_leaves, out_tree = jax.tree_util.tree_flatten(self._call(self.fun, static, in_tree, leaves))
            out_trees.append(out_tree)
            return out_leaves

        specs = [jax.ShapeDtypeStruct(a.shape, a.dtype, weak_type=a.weak_type) for a in avals]
        try:
            exported = jax.export.export(jax.jit(flat))(*specs)
            blob = pickle.dumps({"format": FORMAT, "out_tree": out_trees[-1], "exported": bytes(exported.serialize())})
        except Exception as exc:  # noqa: BLE001 - an export limitation; an error of fun's raises again in the plain jit
            warnings.warn(f"planner graph not exported ({type(exc).__name__}: {exc}); it is traced on every start",
                          ExportWarning, stacklevel=4)
            return None
        return (exported, out_trees[-1]), blob


def _read(path: Path) -> tuple[Any, Any] | None:
    """(Exported, output structure) from ``path``; None when it is missing, unreadable, of another format or does not
    deserialize (a file of another JAX): it is then exported again and replaced."""
    try:
        stored = pickle.loads(path.read_bytes())
        if not isinstance(stored, dict) or stored.get("format") != FORMAT:
            return None
        loaded = jax.export.deserialize(bytearray(stored["exported"])), stored["out_tree"]
    except Exception:  # noqa: BLE001 - a missing, damaged or foreign file is a cache miss
        return None
    with contextlib.suppress(OSError):
        os.utime(path)  # recently used: kept when the folder is trimmed
    return loaded


def _write(path: Path, blob: bytes) -> None:
    """Write an exported graph to ``path`` (whole or not at all), then trim the folder to :data:`MAX_FILES`."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        atomic_write(path, blob)
    except OSError as exc:
        warnings.warn(f"planner graph not written ({exc}); it is traced again on every start", ExportWarning, stacklevel=5)
        return
    ages = []
    for file in path.parent.glob(f"*{SUFFIX}"):
        with contextlib.suppress(OSError):  # another process may remove it meanwhile
            ages.append((file.stat().st_mtime, file))
    for _, old in sorted(ages)[:-MAX_FILES]:
        with contextlib.suppress(OSError):
            old.unlink()
