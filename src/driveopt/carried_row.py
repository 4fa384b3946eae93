"""What a batch's row for the previous plan is (``Method.carried_row``), when a planner carries its previous plan.

A planner that carries its plan from call to call (``plan(..., previous=...)``: :func:`driveopt.planner.previous_plan`)
adds one row for it to every batch, ranked like any sample. Two forms of that row:

- :class:`ResolvedSetpoints` (the default, P1's): the previous plan's set-points, solved by the set-point QP from the
  current state like any sample; the projection takes that new trajectory to the constraints from scratch.
- :class:`ShiftedPlan`: the previous plan's own trajectory, moved on by the time since it was planned
  (``PreviousPlan.coeffs``), as the row's target (and so the projection's first iterate). It was feasible a call
  ago, so it stays near the feasible set and converges within few iterations, where the re-solved set-points can
  need the projection's whole budget: with P2's barrier pass cut to 50 accelerated iterations, ``cvae-filter`` on
  ``highway-v0`` lost its re-solved previous-plan row just outside the feasibility tolerance (residual 0.059 against
  0.0008 after 100 plain iterations) and drove its learned prior's slower rows; the shifted plan's row ends at
  0.0003 after 20 accelerated iterations as after 100 plain ones (docs/results/speed.md).

Both are frozen dataclasses, part of the planner's static method.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import jax.numpy as jnp


class CarriedRow(Protocol):
    needs_trajectory: bool  # whether the row reads PreviousPlan.coeffs (plan() refuses a previous plan without them)

    def row(self, resolved: jnp.ndarray, previous: Any) -> jnp.ndarray:
        """The row's target coefficients (2n,), given the set-point QP's solution for the previous plan's set-points
        (``resolved``) and the previous plan (a :class:`~driveopt.planner.PreviousPlan`; ``present`` False: the absent
        plan's placeholder, a row never ranked)."""
        ...


@dataclass(frozen=True)
class ResolvedSetpoints:
    """The previous plan's set-points re-solved from the current state (P1's row)."""

    needs_trajectory = False

    def row(self, resolved: jnp.ndarray, previous: Any) -> jnp.ndarray:
        return resolved


@dataclass(frozen=True)
class ShiftedPlan:
    """The previous plan's own trajectory, moved on to this call (``PreviousPlan.coeffs``), as the row's target."""

    needs_trajectory = True

    def row(self, resolved: jnp.ndarray, previous: Any) -> jnp.ndarray:
        return jnp.where(previous.present, jnp.asarray(previous.coeffs, resolved.dtype), resolved)
