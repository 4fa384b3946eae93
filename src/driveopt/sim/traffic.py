"""Neighbour vehicles that highway-env can spawn in place of its own (``other_vehicles_type``).

Upstream's IDM vehicles may roll backwards: ``Vehicle.MIN_SPEED`` is -40 m/s, and an IDM car that
brakes hard for a stopped leader integrates its speed below zero. Both traced crashes that every
optimiser shared involved such a reversing car
(docs/findings/closed-loop-defaults.md, "Earlier A/Bs"). :class:`ForwardIDMVehicle` is the same
IDM/MOBIL driver that stops at 0 m/s instead; a scenario chooses it with ``traffic_reverses=False``.
"""

from __future__ import annotations

from highway_env.vehicle.behavior import IDMVehicle


class ForwardIDMVehicle(IDMVehicle):
    """Upstream's IDM/MOBIL vehicle whose speed never goes below 0 m/s."""

    def step(self, dt: float) -> None:
        super().step(dt)
        if self.speed < 0.0:
            self.speed = 0.0
