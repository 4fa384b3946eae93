"""What rides in every sampler batch besides the samples.

:class:`StopRows` (driveopt's default) appends the fallback's comfortable and emergency stops
(:meth:`driveopt.fallback.Fallback.stops`) to every batch: projected and ranked like any sample, so a stop that meets
the constraints can be the chosen plan, and the elite set can learn from it. :class:`SamplesOnly` is P1's batch: the
samples alone. (The previous replan's row rides in either when :func:`driveopt.planner.plan` is given one.) Both are
frozen dataclasses that :func:`driveopt.planner.solve` takes as a static argument.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from driveopt.fallback import Fallback


class BatchRows(Protocol):
    def stops(self, fallback: Fallback, a_max: float) -> tuple[tuple[float, str], ...]:
        """(deceleration [m/s^2], lateral target) of each stop appended to a batch, in row order."""
        ...


@dataclass(frozen=True)
class StopRows:
    """The comfortable and the emergency stop of ``fallback`` ride in every batch."""

    def stops(self, fallback: Fallback, a_max: float) -> tuple[tuple[float, str], ...]:
        return fallback.stops(a_max)


@dataclass(frozen=True)
class SamplesOnly:
    """No stop rides in the batches (P1)."""

    def stops(self, fallback: Fallback, a_max: float) -> tuple[tuple[float, str], ...]:
        return ()
