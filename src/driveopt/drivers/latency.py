"""How the closed loop pays for planning time: the latency strategies of an optimiser driver.

:class:`Synchronous` (the default) stops the simulator while the planner computes: every plan takes effect at the
step it was started from, however long it took. The real-time strategies let the simulator run on: while a plan is
being computed the car keeps executing the previous one, and the new plan takes effect after its compute time
rounded up to policy periods, at least one (:func:`periods_after`). :class:`Measured` takes the call's measured wall
time, :class:`Fixed` a given time in milliseconds (deterministic: same seed, same episode). A plan is made from the
state predicted for the step it will take effect, and tracked from its start when it arrives then
(:class:`driveopt.drivers.optimiser.OptimiserDriver`).

:func:`parse_latency` reads the spellings of ``--latency`` and of the bench option: ``"sync"``, ``"measured"`` or a
number of milliseconds in [0, :data:`MAX_LATENCY_MS`]; :attr:`option` is the value a bench folder records (None for
synchronous, so that synchronous folders keep their settings).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any

from driveopt.errors import DriveoptError

MAX_LATENCY_MS = 10_000.0  # [ms] the longest fixed compute time accepted (100 periods at 10 Hz)
_ROUNDING = 1e-9  # [periods] 0.3 s / 0.1 s is 2.9999999999999996 in floating point: still 3 periods


class LatencyError(DriveoptError):
    """A latency that is neither ``sync``, ``measured`` nor a number of milliseconds in [0, MAX_LATENCY_MS]."""


def periods_after(seconds: float, period: float) -> int:
    """[policy periods] after which a plan computed in ``seconds`` [s] takes effect with policy period ``period`` [s]:
    the compute time rounded up to whole periods, at least one (the earliest next step)."""
    return max(1, math.ceil(seconds / period - _ROUNDING))


@dataclasses.dataclass(frozen=True)
class Synchronous:
    """The simulator waits for every plan: each takes effect at the step it started from (0 periods)."""

    realtime = False
    option = None  # bench option value: none recorded

    def periods(self, seconds: float, period: float) -> int:
        """0: the plan computed in ``seconds`` [s] takes effect at once."""
        return 0


@dataclasses.dataclass(frozen=True)
class Measured:
    """Real time: a plan takes effect after its measured compute time, rounded up to policy periods (at least one)."""

    realtime = True
    option = "measured"

    def periods(self, seconds: float, period: float) -> int:
        """:func:`periods_after` the call's measured wall time ``seconds`` [s]."""
        return periods_after(seconds, period)


@dataclasses.dataclass(frozen=True)
class Fixed:
    """Real time with a fixed compute time ``ms`` [ms] in [0, MAX_LATENCY_MS], whatever the call took."""

    ms: float

    realtime = True

    def __post_init__(self) -> None:
        value = self.ms
        if not (isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
                and 0.0 <= value <= MAX_LATENCY_MS):
            raise LatencyError(f"latency must be 'sync', 'measured' or a number of milliseconds in "
                               f"[0, {MAX_LATENCY_MS:g}], got {value!r}")
        object.__setattr__(self, "ms", float(value))

    @property
    def option(self) -> float:
        """The bench option value: the compute time [ms]."""
        return self.ms

    def periods(self, seconds: float, period: float) -> int:
        """:func:`periods_after` ``ms``, whatever the call took (``seconds`` is ignored)."""
        return periods_after(self.ms / 1e3, period)


Latency = Synchronous | Measured | Fixed


def parse_latency(value: Any) -> Latency:
    """The latency strategy that ``value`` spells: None or ``"sync"``, ``"measured"``, a number of milliseconds (or
    its text), or a strategy (returned as it is); LatencyError for anything else."""
    if isinstance(value, (Synchronous, Measured, Fixed)):
        return value
    if value is None or value == "sync":
        return Synchronous()
    if value == "measured":
        return Measured()
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise LatencyError(f"latency must be 'sync', 'measured' or a number of milliseconds, got {value!r}") from None
    return Fixed(value)
