"""What every command shares: the usage error, argument types, and planner-config files."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

from driveopt.config import from_dict
from driveopt.errors import DriveoptError


class UsageError(DriveoptError):
    """A user-facing error of the command line (a file that cannot be read, a missing option)."""


def _int_at_least(text: str, low: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"expected an integer >= {low}, got {value}")
    return value


def positive_int(text: str) -> int:
    return _int_at_least(text, 1)


def non_negative_int(text: str) -> int:
    return _int_at_least(text, 0)


MAX_SEED = 2**32 - 1  # seeds feed both JAX's PRNG and highway-env's numpy generator


def seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer seed, got {text!r}") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"seed must be in [0, {MAX_SEED}], got {value}")
    return value


def writable_file(path: str | None, what: str) -> None:
    """Refuse, before any work, an output path that is a directory or whose folder cannot be written."""
    if not path:
        return
    target = Path(path)
    if target.is_dir():
        raise UsageError(f"{what} {path} is a directory; give a file path")
    folder = target.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir() or not os.access(folder, os.W_OK):
        raise UsageError(f"{what} {path} cannot be written (no writable folder {folder})")
    if target.exists() and not os.access(target, os.W_OK):
        raise UsageError(f"{what} {path} cannot be written (permission denied)")


def config_overrides(path: str | None, filter_weights: str | None = None) -> dict[str, Any]:
    """Planner-config overrides from a JSON file (nested sections), checked against the config schema; an optional
    ``safety_filter`` section ``{"weights": FILE}`` names a learned safety filter checkpoint, and so does
    ``filter_weights`` (``--filter-weights``, which wins)."""
    data: Any = {}
    if path:
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise UsageError(f"cannot read config {path}: {exc}") from None
    if isinstance(data, dict):
        from driveopt.safety.learned import FILTER_SECTION, split_filter_section

        from_dict(split_filter_section(data)[0])  # unknown sections, keys or bad values: ConfigError
        if filter_weights:
            data = {**data, FILTER_SECTION: {"weights": filter_weights}}
    else:
        from_dict(data)  # not a mapping: ConfigError
    return data


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as indented JSON, creating the folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1))
    return path
