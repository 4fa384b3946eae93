"""benchmarks/studies/upstream_roads.py with the pace of a route's lane changes overridden (fields of
driveopt.sim.route_goal.RouteChange), for A/Bs of the pace:

    python benchmarks/studies/route_change_ab.py comfortable_lane_time=2.0 -- --out OUT --envs exit-v0 --planners bilevel
"""

import functools
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import driveopt.drivers.optimiser as optimiser  # noqa: E402
from driveopt.sim.perception import RoadPreview  # noqa: E402
from driveopt.sim.route_goal import RouteChange  # noqa: E402

import upstream_roads  # noqa: E402


def main(argv: list[str]) -> int:
    if "--" not in argv:
        raise SystemExit("usage: route_change_ab.py FIELD=VALUE ... -- UPSTREAM_ROADS_ARGS")
    split = argv.index("--")
    try:
        fields = {name: float(value) for name, value in (a.split("=", 1) for a in argv[:split])}
        pace = RouteChange(**fields)
    except (ValueError, TypeError) as exc:
        raise SystemExit(f"route_change_ab.py: {exc}") from None
    optimiser.RoadPreview = functools.partial(RoadPreview, route_change=pace)
    return upstream_roads.main(argv[split + 1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
