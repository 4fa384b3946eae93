"""What every command shares: the usage error, argument types, planner-config files, and the checks and writers of
output files."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from driveopt import files
from driveopt.config import from_dict
from driveopt.errors import DriveoptError
from driveopt.files import check_output_file


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


def add_split_arguments(p) -> None:
    """The trainers' options for the validation split, the training subset and the seed."""
    p.add_argument("--validation", type=float, default=0.1, help="share of episodes held out for validation")
    p.add_argument("--validation-data", nargs="+", help="hold out these demonstration files instead (--validation unused)")
    p.add_argument("--train-episodes", type=int, default=0,
                   help="learn from only this many of the other episodes (0: all; the held-out ones stay the same)")
    p.add_argument("--seed", type=seed, default=0, help="initialisation, split and minibatch seed")


def positive_int(text: str) -> int:
    return _int_at_least(text, 1)


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text}")
    return value


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


def writable_file(path: str | None, what: str, suffixes: tuple[str, ...] = ()) -> None:
    """Refuse, before any work, an output path that cannot take the file (:func:`driveopt.files.check_output_file`:
    a folder, a device, an extension not in ``suffixes``, a folder that cannot be written); nothing when no path is
    given."""
    if path:
        check_output_file(path, what, suffixes)


def config_overrides(path: str | None, filter_weights: str | None = None) -> dict[str, Any]:
    """Planner-config overrides from a JSON file (nested sections, read by :func:`driveopt.jsonfile.read_json`),
    checked against the config schema; an optional
    ``safety_filter`` section ``{"weights": FILE}`` names a learned safety filter checkpoint, and so does
    ``filter_weights`` (``--filter-weights``, which wins)."""
    from driveopt.jsonfile import JSONFileError, read_json

    data: Any = {}
    if path:
        try:
            data = read_json(path, "config")  # special files, huge files, deep nesting, huge numbers: refused
        except JSONFileError as exc:
            raise UsageError(f"cannot read {exc}") from None
    if isinstance(data, dict):
        from driveopt.safety.learned import FILTER_SECTION, split_filter_section

        from_dict(split_filter_section(data)[0])  # unknown sections, keys or bad values: ConfigError
        if filter_weights:
            data = {**data, FILTER_SECTION: {"weights": filter_weights}}
    else:
        from_dict(data)  # not a mapping: ConfigError
    return data


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as indented strict JSON (no NaN or Infinity: a missing number is null), whole or not at all,
    creating the folder; OutputError (one line) when it cannot be written."""
    return files.write_json(path, data)
