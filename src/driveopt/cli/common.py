"""What every command shares: the usage error, argument types, and planner-config files."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from driveopt.config import from_dict
from driveopt.errors import DriveoptError


class UsageError(DriveoptError):
    """A user-facing error of the command line (a file that cannot be read, a missing option)."""


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


def config_overrides(path: str | None) -> dict[str, Any]:
    """Planner-config overrides from a JSON file (nested sections), checked against the config schema."""
    if not path:
        return {}
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UsageError(f"cannot read config {path}: {exc}") from None
    from_dict(data)  # unknown sections, keys or bad values: ConfigError
    return data


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as indented JSON, creating the folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1))
    return path
