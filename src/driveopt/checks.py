"""Checks of configuration values with one-line errors: types of dataclass fields, numbers in ranges, counts.

Every configuration dataclass (the planner's sections, the scenarios, the networks and the trainers) validates
itself in ``__post_init__`` with these, so a bad value is reported where it was given, naming the field.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any

from driveopt.errors import DriveoptError


class ConfigError(DriveoptError):
    """A configuration value is malformed or out of range."""


def require(cond: bool, message: str) -> None:
    if not cond:
        raise ConfigError(message)


_EXPECTED = {"bool": "true or false", "int": "an integer", "float": "a number"}


def check_types(config: Any, section: str) -> None:
    """Every field of the dataclass ``config`` has its declared type (a bool is a bool, an int an int
    and not a bool, a float a real number and not a bool) and every float is finite; an int given for
    a float field becomes a float. JSON values are never coerced (``"false"`` is not false)."""
    for f in dataclasses.fields(config):
        if f.type not in _EXPECTED:
            continue  # nested sections check themselves
        value = getattr(config, f.name)
        name = f"{section}.{f.name}" if section else f.name
        if f.type == "bool":
            ok = isinstance(value, bool)
        elif f.type == "int":
            ok = isinstance(value, int) and not isinstance(value, bool)
        else:
            ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
        require(ok, f"{name} must be {_EXPECTED[f.type]}, got {value!r}")
        if f.type == "float":
            require(math.isfinite(value), f"{name} must be finite, got {value!r}")
            object.__setattr__(config, f.name, float(value))


def check_number(name: str, value: Any, low: float, high: float = math.inf, *, low_open: bool = False,
                 high_open: bool = False, unit: str = "") -> None:
    """ConfigError naming ``name`` unless ``value`` is a finite real number (not a bool) between ``low``
    and ``high``, each bound included unless ``low_open`` / ``high_open``; ``unit`` goes into the message."""
    real = isinstance(value, numbers.Real) and not isinstance(value, bool)
    ok = real and math.isfinite(value) and (low < value if low_open else low <= value) and (
        value < high if high_open else value <= high)
    if not ok:
        lower = f"> {low:g}" if low_open else f">= {low:g}"
        upper = "" if high == math.inf else f" and {'<' if high_open else '<='} {high:g}"
        raise ConfigError(f"{name} must be a finite number {lower}{upper}{' ' + unit if unit else ''}, got {value!r}")


def check_count(name: str, value: Any, minimum: int = 1) -> None:
    """ConfigError naming ``name`` unless ``value`` is an integer (not a bool) >= ``minimum``."""
    if not (isinstance(value, numbers.Integral) and not isinstance(value, bool) and value >= minimum):
        raise ConfigError(f"{name} must be an integer >= {minimum}, got {value!r}")
