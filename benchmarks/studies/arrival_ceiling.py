"""The earliest time any car can reach the destination of upstream highway-env's routed envs under the planner's
bounds, with no traffic: the route's roads from the ego's start to the start of the route's last road, each road on
whichever of its lanes is quickest (lane changes cost nothing), driven at the fastest speed profile that keeps the
lateral acceleration v^2 |curvature| within a bound, |dv/dt| within the acceleration bound and v within a speed cap,
from the ego's speed at reset (a lower bound on any car's arrival time under those bounds):

    python benchmarks/studies/arrival_ceiling.py --out OUT.json [--envs roundabout-v0 ...] [--episodes 20]
        [--bounds 4 6 8] [--acceleration 4.5] [--speed-cap 30]

An episode can count as arrived (benchmarks/studies/upstream_roads.py: the ego on the route's last road at a policy
step) only if this time is within the env's duration.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from upstream_roads import make_env  # noqa: E402

ROUTED_ENVS = ("roundabout-v0", "intersection-v0", "u-turn-v0", "roundabout-generic-v0")
STEP = 0.25  # [m] spacing of the speed profile's samples along the route


def fastest_time(curvature: np.ndarray, start_speed: float, bound: float, acceleration: float, cap: float) -> float:
    """[s] time over samples :data:`STEP` apart with |``curvature``| [1/m] at each, from ``start_speed`` [m/s]: the
    fastest profile with v^2 |curvature| <= ``bound`` [m/s^2], |dv/ds| v <= ``acceleration`` [m/s^2], v <= ``cap``
    [m/s] (the usual forward and backward passes; the start may exceed the first samples' limits, then it brakes)."""
    limit = np.minimum(cap, np.sqrt(bound / np.maximum(np.abs(curvature), 1e-9)))
    v = limit.copy()
    v[0] = min(start_speed, cap)
    for i in range(1, len(v)):  # accelerate as far as allowed
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2.0 * acceleration * STEP))
    for i in range(len(v) - 2, -1, -1):  # brake in time for what follows
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2.0 * acceleration * STEP))
    if v[0] < min(start_speed, cap):  # arriving faster than the first limits allow: brake from the start speed
        v[0] = min(start_speed, cap)
    mean = 0.5 * (v[1:] + v[:-1])
    return float(np.sum(STEP / np.maximum(mean, 1e-6)))


def route_roads(sim) -> list[tuple[str, str]]:
    """The roads the ego is routed along, from its own road (its route, else the env's destination)."""
    from driveopt.sim.lane_graph import env_destination_route

    ego = sim.vehicle
    if getattr(ego, "route", None):
        roads = [tuple(index[:2]) for index in ego.route]
        if tuple(ego.lane_index[:2]) not in roads:
            roads.insert(0, tuple(ego.lane_index[:2]))
        return roads[roads.index(tuple(ego.lane_index[:2])):]
    nodes = env_destination_route(sim)
    if not nodes:
        raise SystemExit(f"{sim.spec.id if sim.spec else type(sim).__name__}: no route to a destination")
    return list(zip(nodes[:-1], nodes[1:]))


def road_samples(network, road: tuple[str, str], start: float, bound: float, acceleration: float, cap: float) -> np.ndarray:
    """|curvature| [1/m] at samples :data:`STEP` apart along ``road`` from ``start`` [m], on its quickest lane."""
    from driveopt.sim.road_frame import lane_curvature

    best = None
    for lane in network.graph[road[0]][road[1]]:
        s = np.arange(start, lane.length, STEP)
        if len(s) < 2:
            continue
        kappa = np.array([abs(lane_curvature(lane, float(x))) for x in s])
        time = fastest_time(kappa, cap, bound, acceleration, cap)
        if best is None or time < best[0]:
            best = (time, kappa)
    return np.zeros(0) if best is None else best[1]


def earliest_arrival(sim, bound: float, acceleration: float, cap: float) -> tuple[float, float]:
    """([s] the earliest arrival on the route's last road, [m] the distance to it) from the ego's state now."""
    roads = route_roads(sim)
    network, ego = sim.road.network, sim.vehicle
    start = float(ego.lane.local_coordinates(ego.position)[0])
    pieces = [road_samples(network, road, start if k == 0 else 0.0, bound, acceleration, cap)
              for k, road in enumerate(roads[:-1])]
    kappa = np.concatenate(pieces) if pieces else np.zeros(1)
    if len(kappa) < 2:
        return 0.0, 0.0
    return fastest_time(kappa, float(ego.speed), bound, acceleration, cap), STEP * (len(kappa) - 1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="JSON file for the results")
    parser.add_argument("--envs", nargs="+", default=list(ROUTED_ENVS), choices=ROUTED_ENVS)
    parser.add_argument("--episodes", type=int, default=20, help="seeds 0 .. episodes - 1")
    parser.add_argument("--bounds", type=float, nargs="+", default=[4.0, 6.0, 8.0],
                        help="[m/s^2] lateral-acceleration bounds (the planner's projection.centripetal_max: 4)")
    parser.add_argument("--acceleration", type=float, default=4.5, help="[m/s^2] the planner's projection.a_max")
    parser.add_argument("--speed-cap", type=float, default=30.0, help="[m/s] the planner's projection.v_max")
    args = parser.parse_args(argv)
    if args.episodes < 1 or any(not b > 0 for b in args.bounds) or not args.acceleration > 0 or not args.speed_cap > 0:
        parser.error("--episodes, --bounds, --acceleration and --speed-cap must be positive")
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    from driveopt.files import write_json

    results = {}
    for env_id in args.envs:
        env = make_env(env_id)
        duration = float(env.unwrapped.config["duration"])
        episodes = []
        for seed in range(args.episodes):
            env.reset(seed=seed)
            sim = env.unwrapped
            times = {}
            for bound in args.bounds:
                time, distance = earliest_arrival(sim, bound, args.acceleration, args.speed_cap)
                times[f"{bound:g}"] = round(time, 3)
            episodes.append({"seed": seed, "route": [list(r) for r in route_roads(sim)], "distance_m": round(distance, 2),
                             "start_speed": round(float(sim.vehicle.speed), 3), "earliest_arrival_s": times})
        env.close()
        can_arrive = {b: sum(e["earliest_arrival_s"][b] <= duration for e in episodes) for b in episodes[0]["earliest_arrival_s"]}
        results[env_id] = {"duration_s": duration, "episodes": episodes, "can_arrive": can_arrive}
        print(f"{env_id} (duration {duration:g} s): can arrive in "
              + ", ".join(f"{n} of {len(episodes)} at {b} m/s^2" for b, n in can_arrive.items())
              + "; earliest at the first bound "
              + f"{min(e['earliest_arrival_s'][f'{args.bounds[0]:g}'] for e in episodes):.1f}-"
              + f"{max(e['earliest_arrival_s'][f'{args.bounds[0]:g}'] for e in episodes):.1f} s", flush=True)
    write_json(args.out, {"command": "python benchmarks/studies/arrival_ceiling.py " + " ".join(argv or sys.argv[1:]),
                          "acceleration": args.acceleration, "speed_cap": args.speed_cap, "results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
