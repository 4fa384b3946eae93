"""Neighbour vehicles that highway-env can spawn in place of its own (``other_vehicles_type``).

Upstream's IDM vehicles may roll backwards: ``Vehicle.MIN_SPEED`` is -40 m/s, and an IDM car that
brakes hard for a stopped leader integrates its speed below zero. Both traced crashes that every
optimiser shared involved such a reversing car
(docs/findings/closed-loop-defaults.md, "Earlier A/Bs"). :class:`ForwardIDMVehicle` is the same
IDM/MOBIL driver that stops at 0 m/s instead; a scenario chooses it with ``traffic_reverses=False``.

Upstream's ``intersection-v0`` sets class attributes of its traffic's vehicle class whenever it makes its vehicles
(``IDMVehicle.DISTANCE_WANTED = 7``, ``COMFORT_ACC_MAX = 6``, ``COMFORT_ACC_MIN = -3``), so every env reset later in
the same process drives its traffic with them: an episode then depends on which envs ran before it. A benchmark that
runs several envs in one process takes :func:`traffic_constants` before any env is made and hands them to
:func:`restore_traffic_constants` before each episode.
"""

from __future__ import annotations

from typing import Any

from highway_env.vehicle.behavior import IDMVehicle


class ForwardIDMVehicle(IDMVehicle):
    """Upstream's IDM/MOBIL vehicle whose speed never goes below 0 m/s."""

    def step(self, dt: float) -> None:
        super().step(dt)
        if self.speed < 0.0:
            self.speed = 0.0


def _vehicle_classes() -> list[type]:
    """IDMVehicle and every class derived from it that is loaded now."""
    classes, todo = [], [IDMVehicle]
    while todo:
        cls = todo.pop()
        classes.append(cls)
        todo.extend(cls.__subclasses__())
    return classes


def traffic_constants() -> dict[type, dict[str, Any]]:
    """The upper-case class attributes (the driver's constants) each of upstream's IDM vehicle classes defines itself."""
    return {cls: {name: value for name, value in vars(cls).items() if name.isupper()} for cls in _vehicle_classes()}


def restore_traffic_constants(constants: dict[type, dict[str, Any]]) -> None:
    """Set the classes' constants back to ``constants`` (from :func:`traffic_constants`), removing any an env added."""
    for cls, values in constants.items():
        for name in [n for n in vars(cls) if n.isupper() and n not in values]:
            delattr(cls, name)
        for name, value in values.items():
            setattr(cls, name, value)
