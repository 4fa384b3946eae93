"""CommonRoad scenarios for driveopt's planners (the optional extra ``driveopt[commonroad]``).

:mod:`~driveopt.commonroad.path` (a curvilinear frame along a polyline), :mod:`~driveopt.commonroad.world` (a
scenario as a road frame, lanes, obstacles and a :class:`~driveopt.goal.Goal`), :mod:`~driveopt.commonroad.evaluate`
(the one judge: collision, road boundary, goal), :mod:`~driveopt.commonroad.drive` (driveopt's closed loop),
:mod:`~driveopt.commonroad.fiss` (the FISS planners through the same judge), :mod:`~driveopt.commonroad.bench` (a
folder of scenarios x planners, resumable JSONL). :func:`require` refuses in one line when the extra is missing.
"""

from __future__ import annotations

from driveopt.errors import DriveoptError

EXTRA = "pip install 'driveopt[commonroad]'"
# how the ego moves between time steps: ``perfect`` (where the followed plan is one step later, FISS's benchmark's) or
# ``tracked`` (driveopt's bicycle following the plan with its tracker, driveopt's planners only)
EXECUTIONS = ("perfect", "tracked")


class MissingExtra(DriveoptError):
    """A package of the ``commonroad`` extra is not installed."""


def require(fiss: bool = False) -> None:
    """MissingExtra (one line) unless commonroad-io, the drivability checker and the route planner import (and, with
    ``fiss``, the FISS planner)."""
    import importlib

    modules = ["commonroad.common.file_reader", "commonroad_dc.boundary.boundary", "commonroad_route_planner.route_planner"]
    if fiss:
        modules.append("fiss_planner.commonroad.benchmark")
    for module in modules:
        try:
            importlib.import_module(module)
        except Exception as exc:  # noqa: BLE001 - an ImportError, or a broken install raising on import
            raise MissingExtra(f"the commonroad command needs the commonroad extra ({module} does not import: "
                               f"{type(exc).__name__}: {' '.join(str(exc).split())[:100]}); {EXTRA}") from None
