"""Checks of configuration values with one-line errors: types of dataclass fields, numbers in ranges, counts,
and estimates of work and memory within limits that ``DRIVEOPT_ALLOW_LARGE=1`` lifts.

Every configuration dataclass (the planner's sections, the scenarios, the networks and the trainers) validates
itself in ``__post_init__`` with these, so a bad value is reported where it was given, naming the field.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import numbers
import os
from collections.abc import Sequence
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


ALLOW_LARGE = "DRIVEOPT_ALLOW_LARGE"
"""Environment variable: set to 1 to run work or memory estimates above their limits (:func:`check_budget`)."""

MAX_PARAMETERS = 50_000_000  # [-] network parameters; 200 MB in float32, ~800 MB while training (weights,
# gradients, two Adam moments); the shipped networks have under 1 M, a CVAE of P1's widths (4 x 1024 + 256) 7 M


def large_allowed() -> bool:
    """Whether the user opted in to estimates above the limits (``DRIVEOPT_ALLOW_LARGE`` set, and not to 0)."""
    return os.environ.get(ALLOW_LARGE, "").strip() not in ("", "0")


def check_budget(what: str, estimate: float, limit: float, meaning: str) -> None:
    """ConfigError unless the estimate of a call's work or memory is within ``limit`` or the user opted in;
    ``meaning`` says what the estimate amounts to (time, bytes), so the user can judge whether to opt in.

    The limits refuse what cannot finish or allocate on an ordinary machine before any work starts, rather
    than failing after minutes with an out-of-memory traceback or running for hours."""
    if estimate > limit and not large_allowed():
        raise ConfigError(f"{what} is {estimate:.3g} ({meaning}), above the limit of {limit:.3g}; "
                          f"set {ALLOW_LARGE}=1 to run it anyway")


def dense_parameters(sizes: Sequence[int]) -> int:
    """Weights and biases of a chain of dense layers of ``sizes`` (input, hidden widths..., output)."""
    return sum(a * b + b for a, b in itertools.pairwise(sizes))


def check_parameters(name: str, count: int) -> None:
    """ConfigError unless a network of ``count`` parameters is within MAX_PARAMETERS (or the user opted in)."""
    check_budget(f"{name}: the parameter count of its networks", count, MAX_PARAMETERS,
                 f"{4 * count / 1e9:.3g} GB of float32 weights, about 4 times that while training")
