"""Checkpoint files: a JSON header line, then the msgpack body (flax.serialization) it checksums.

    {"format": "driveopt-checkpoint", "schema_version": 1, "kind": "cvae", "sha256": ..., "meta": {...}}\\n
    <msgpack of the state dict>

``meta`` is the writer's (for the CVAE: configuration, training settings, the data record with the
validation split, the lane counts of the training roads, history; see
:mod:`driveopt.training.cvae`). Adding a field to the header changes neither the body nor its
checksum, so the weights stay byte-identical.

Writes are atomic (a temporary file in the same folder, fsynced, then renamed), so an interrupted
save leaves the previous checkpoint intact. Loading checks the format, version, kind and checksum
and raises :class:`CheckpointError` with the reason, never returns a partly read state.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from flax import serialization

from driveopt.errors import DriveoptError
from driveopt.files import atomic_write

FORMAT = "driveopt-checkpoint"
SCHEMA_VERSION = 1


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
        raw = path.read_bytes()
    except OSError as exc:
        raise CheckpointError(f"cannot read checkpoint {path}: {exc.strerror or exc}") from None
    line, sep, body = raw.partition(b"\n")
    try:
        header = json.loads(line) if sep else None
    except (json.JSONDecodeError, UnicodeDecodeError):
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


def restore(target: Any, state: dict[str, Any], path: str | Path, what: str) -> Any:
    """``target``'s structure filled from ``state``; CheckpointError when the shapes do not match."""
    try:
        restored = serialization.from_state_dict(target, state)
    except (ValueError, KeyError, TypeError) as exc:
        raise CheckpointError(f"{path}: {what} does not match the model: {exc}") from None
    import jax
    import numpy as np

    for want, got in zip(jax.tree_util.tree_leaves(target), jax.tree_util.tree_leaves(restored)):
        if np.shape(want) != np.shape(got):
            raise CheckpointError(f"{path}: {what} has an array of shape {np.shape(got)}, the model needs {np.shape(want)}")
    return restored
