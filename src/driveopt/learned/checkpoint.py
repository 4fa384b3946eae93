"""Checkpoint files: a JSON header line, then the msgpack body (flax.serialization) it checksums.

    {"format": "driveopt-checkpoint", "schema_version": 1, "kind": "cvae", "sha256": ..., "meta": {...}}\\n
    <msgpack of the state dict>

``meta`` is the writer's (for the CVAE: configuration, training settings, the data record with the
validation split, the lane counts of the training roads, history; see
:mod:`driveopt.training.cvae`). Adding a field to the header changes neither the body nor its
checksum, so the weights stay byte-identical.

Writes are atomic (a temporary file in the same folder, fsynced, then renamed), so an interrupted
save leaves the previous checkpoint intact. Loading checks the format, version, kind and checksum,
that ``meta`` is a mapping, and (:func:`restore`) that every array has the model's shape and holds
finite values of a sane magnitude, and the loaders that every normaliser scale is positive: a
checksum only proves the file is the one written, and a trainer that diverged writes NaN faithfully.
It raises :class:`CheckpointError` with the reason, never returns a partly read or unusable state.
"""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path
from typing import Any, Callable

import numpy as np
from flax import serialization

from driveopt.errors import DriveoptError
from driveopt.files import atomic_write
from driveopt.jsonfile import JSONFileError, parse_json

FORMAT = "driveopt-checkpoint"
SCHEMA_VERSION = 1
MAX_MAGNITUDE = 1e6  # [-] largest absolute value of a weight or statistic accepted (the shipped ones stay under 1e3;
# a value of 1e30 is finite, but turns the networks' outputs into inf and the plans into NaN)
MIN_SCALE = 1e-6  # [-] smallest normaliser standard deviation accepted (the trainers floor theirs at 1e-3)


class CheckpointError(DriveoptError):
    """A checkpoint is missing, corrupted, of another kind or version, or does not match its use."""


def save_checkpoint(path: str | Path, kind: str, state: Any, meta: dict[str, Any]) -> Path:
    """Write ``state`` (a pytree of arrays) with JSON-ready ``meta`` to ``path`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    body = serialization.msgpack_serialize(serialization.to_state_dict(state))
    header = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "kind": kind,
              "sha256": hashlib.sha256(body).hexdigest(), "meta": meta}
    return atomic_write(path, json.dumps(header).encode() + b"\n" + body)


def load_checkpoint(path: str | Path, kind: str, lanes: int | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
    """(meta, state dict) of a checkpoint of ``kind``; CheckpointError on any problem, or when ``lanes`` is given
    and the checkpoint was trained for roads with other lane counts (:func:`check_lanes`)."""
    path = Path(path)
    try:
        if path.exists() and not path.is_file():
            raise CheckpointError(f"cannot read checkpoint {path}: not a regular file")
        raw = path.read_bytes()
    except OSError as exc:
        raise CheckpointError(f"cannot read checkpoint {path}: {exc.strerror or exc}") from None
    line, sep, body = raw.partition(b"\n")
    try:
        header = parse_json(line.decode("utf-8"), f"checkpoint {path}") if sep else None
    except (JSONFileError, UnicodeDecodeError):
        header = None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a driveopt checkpoint (bad header)")
    if header.get("schema_version") != SCHEMA_VERSION:
        raise CheckpointError(f"{path} has checkpoint schema {header.get('schema_version')}; this driveopt reads {SCHEMA_VERSION}")
    if header.get("kind") != kind:
        raise CheckpointError(f"{path} holds a '{header.get('kind')}' model, expected '{kind}'")
    if hashlib.sha256(body).hexdigest() != header.get("sha256"):
        raise CheckpointError(f"{path} is corrupted (checksum mismatch: truncated or modified)")
    try:
        state = serialization.msgpack_restore(body)
    except Exception as exc:  # msgpack raises several types on malformed input
        raise CheckpointError(f"{path} is corrupted: {exc}") from None
    meta = header.get("meta", {})
    if not isinstance(meta, dict):
        raise CheckpointError(f"{path} has an invalid header: 'meta' must be an object, got {type(meta).__name__}")
    if lanes is not None:
        check_lanes(meta, lanes, path)
    return meta, state


def check_lanes(meta: dict[str, Any], lanes: int, path: str | Path) -> None:
    """CheckpointError unless the checkpoint's ``meta["lanes"]`` (the lane counts of the roads of its
    training demonstrations) includes ``lanes``.

    A checkpoint without the record (written before driveopt recorded it) is accepted unchecked: a
    user's older weights keep working, and nothing in them tells the road; the shipped weights carry it.
    """
    trained = meta.get("lanes")
    if trained is None:
        return
    if not isinstance(trained, list) or not all(isinstance(n, int) and not isinstance(n, bool) for n in trained):
        raise CheckpointError(f"{path}: invalid lane record {trained!r} in the header (expected a list of lane counts)")
    if int(lanes) not in trained:
        roads = " or ".join(str(n) for n in trained)
        raise CheckpointError(f"{path} was trained for {roads}-lane roads, not this {int(lanes)}-lane road: "
                              f"use weights trained on {int(lanes)}-lane demonstrations")


def header_config(meta: dict[str, Any], path: str | Path, config_type: Any, what: str, key: str = "config") -> Any:
    """``config_type.from_dict(meta[key])``: the model configuration recorded in a checkpoint's header;
    CheckpointError naming ``what`` (e.g. "CVAE") when it is missing or invalid."""
    try:
        return config_type.from_dict(meta[key])
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{path}: invalid {what} config in the header: {exc}") from None


@functools.cache
def parameter_shapes(init_params: Callable[[Any, Any], Any], cfg: Any) -> Any:
    """The structure of ``init_params(cfg, key)``: its arrays' shapes and dtypes, traced once per network and
    configuration (``cfg`` hashable), not computed; the target that :func:`restore` fills from a checkpoint (a
    benchmark builds the same planners' priors many times: each load reuses it)."""
    import jax

    return jax.eval_shape(lambda key: init_params(cfg, key), jax.random.PRNGKey(0))


def restore(target: Any, state: dict[str, Any], path: str | Path, what: str, unbounded: tuple[str, ...] = ()) -> Any:
    """``target``'s structure filled from ``state``; CheckpointError when the shapes do not match, or when an array
    holds NaN, an infinity or (outside the top-level entries ``unbounded``) a value beyond +-MAX_MAGNITUDE.

    ``unbounded`` names state whose size says nothing of divergence, such as an optimiser's: Adam's second moment is
    the running mean of squared gradients (above 1e6 for gradients of 1e3, as a loss in the thousands has) and its step
    counter passes 1e6 in a long run."""
    try:
        restored = serialization.from_state_dict(target, state)
    except (ValueError, KeyError, TypeError) as exc:
        raise CheckpointError(f"{path}: {what} does not match the model: {exc}") from None
    import jax

    for want, got in zip(jax.tree_util.tree_leaves(target), jax.tree_util.tree_leaves(restored)):
        if np.shape(want) != np.shape(got):
            raise CheckpointError(f"{path}: {what} has an array of shape {np.shape(got)}, the model needs {np.shape(want)}")
    for name, values in _named_leaves(restored):
        values = np.asarray(values)
        if values.dtype.kind in "fc" and not np.all(np.isfinite(values)):
            raise CheckpointError(f"{path}: {what} holds NaN or infinite values (in {name}): the training diverged")
        bounded = not (isinstance(restored, dict) and any(name.startswith(f"[{key!r}]") for key in unbounded))
        if bounded and values.dtype.kind in "fciu" and values.size and np.max(np.abs(values)) > MAX_MAGNITUDE:
            raise CheckpointError(f"{path}: {what} holds values beyond +-{MAX_MAGNITUDE:g} (in {name}): the training "
                                  "diverged")
    return restored


def check_scales(path: str | Path, what: str, scales: dict[str, Any]) -> None:
    """CheckpointError unless every normaliser standard deviation in ``scales`` (name -> array) is at least
    MIN_SCALE: inputs are divided by them, and a zero turns every plan into NaN."""
    for name, values in scales.items():
        values = np.asarray(values)
        if values.size and not np.min(values) >= MIN_SCALE:
            raise CheckpointError(f"{path}: {what} has a normaliser scale below {MIN_SCALE:g} (in {name}, "
                                  f"{float(np.min(values)):g}): inputs are divided by it")


def _named_leaves(tree: Any) -> list[tuple[str, Any]]:
    """(path as text, array) of every leaf of ``tree``, for messages that say where a bad value is."""
    import jax

    return [(jax.tree_util.keystr(keys), leaf) for keys, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]]
