"""benchmarks/studies/upstream_roads.py with fields of the controller's road preview overridden
(:class:`driveopt.sim.perception.RoadPreview`; ``route_change.FIELD`` for the pace of a route's lane changes before a
split, :class:`driveopt.sim.route_goal.RouteChange`), for A/Bs of the preview on the same episodes:

    python benchmarks/studies/preview_ab.py route_change.comfortable_lane_time=2.0 -- --out OUT --envs exit-v0 --planners bilevel
    python benchmarks/studies/preview_ab.py curvature_per_node=true -- --out OUT --envs racetrack-v0 --planners bilevel
"""

import functools
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import driveopt.drivers.optimiser as optimiser  # noqa: E402
from driveopt.sim.perception import RoadPreview  # noqa: E402
from driveopt.sim.route_goal import RouteChange  # noqa: E402

import upstream_roads  # noqa: E402


_BOOLEANS = {"true": True, "false": False}


def _value(text: str) -> float | bool:
    """``true`` / ``false`` (any case) as a bool, anything else as a number."""
    return _BOOLEANS[text.lower()] if text.lower() in _BOOLEANS else float(text)


def preview_fields(assignments: list[str]) -> dict:
    """``FIELD=VALUE`` and ``route_change.FIELD=VALUE`` strings -> RoadPreview keyword arguments (numbers, or true and
    false)."""
    fields, pace = {}, {}
    for assignment in assignments:
        name, equals, value = assignment.partition("=")
        if not equals:
            raise ValueError(f"{assignment!r} is not FIELD=VALUE")
        target, name = (pace, name.removeprefix("route_change.")) if name.startswith("route_change.") else (fields, name)
        target[name] = _value(value)
    if pace:
        fields["route_change"] = RouteChange(**pace)
    RoadPreview(**fields)  # refuses unknown fields and out-of-range values here, before any episode
    return fields


def main(argv: list[str]) -> int:
    if "--" not in argv:
        raise SystemExit("usage: preview_ab.py FIELD=VALUE ... -- UPSTREAM_ROADS_ARGS")
    split = argv.index("--")
    try:
        fields = preview_fields(argv[:split])
    except (ValueError, TypeError) as exc:
        raise SystemExit(f"preview_ab.py: {exc}") from None
    optimiser.RoadPreview = functools.partial(RoadPreview, **fields)
    return upstream_roads.main(argv[split + 1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
