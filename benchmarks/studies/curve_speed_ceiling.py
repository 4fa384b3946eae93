"""The fastest mean speed a lateral-acceleration bound allows on a racetrack: each lane of the loop driven at
min(its speed limit, sqrt(bound / |curvature|)), changing speed instantly (an upper bound on any car's mean speed
over a lap under that bound):

    python benchmarks/studies/curve_speed_ceiling.py --out OUT.json [--bounds 4 6 8] [--envs racetrack-v0 ...]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path


def lanes(env_id: str) -> list[dict]:
    """Each road of the env's loop: its first lane's length [m], |curvature| [1/m] and speed limit [m/s]."""
    import gymnasium as gym
    import highway_env  # noqa: F401  (registers the envs)
    from highway_env.road.lane import CircularLane

    env = gym.make(env_id)
    env.reset(seed=0)
    out = []
    for start, ends in env.unwrapped.road.network.graph.items():
        for end, road in ends.items():
            lane = road[0]
            kappa = 1.0 / lane.radius if isinstance(lane, CircularLane) else 0.0
            out.append({"road": [start, end], "length": float(lane.length), "curvature": kappa,
                        "speed_limit": float(lane.speed_limit)})
    env.close()
    return out


def ceiling(roads: list[dict], bound: float) -> float:
    """[m/s] lap length over the lap's time at min(speed limit, sqrt(bound / |curvature|)) on each road."""
    time = sum(r["length"] / (min(r["speed_limit"], math.sqrt(bound / r["curvature"])) if r["curvature"] > 0
                              else r["speed_limit"]) for r in roads)
    return sum(r["length"] for r in roads) / time


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="JSON file for the results")
    parser.add_argument("--bounds", type=float, nargs="+", default=[4.0, 6.0, 8.0], help="[m/s^2] lateral bounds")
    parser.add_argument("--envs", nargs="+", default=["racetrack-v0", "racetrack-oval-v0", "racetrack-large-v0"])
    args = parser.parse_args(argv)
    if any(not b > 0 for b in args.bounds):
        parser.error("--bounds must be positive")
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    from driveopt.files import write_json

    results = {}
    for env_id in args.envs:
        roads = lanes(env_id)
        results[env_id] = {"roads": roads, "ceiling_mps": {f"{b:g}": ceiling(roads, b) for b in args.bounds}}
        print(env_id, ", ".join(f"{b} m/s^2: {v:.2f} m/s" for b, v in results[env_id]["ceiling_mps"].items()), flush=True)
    write_json(args.out, {"command": "python benchmarks/studies/curve_speed_ceiling.py " + " ".join(argv or sys.argv[1:]),
                          "results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
