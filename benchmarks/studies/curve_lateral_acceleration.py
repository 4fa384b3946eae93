"""How hard the controller's car turns on upstream's curved envs, in the world: at each policy step its speed v [m/s]
and the lane it is on (the simulator's nearest), ``v^2 / R`` [m/s^2] on a circular lane (0 elsewhere), against the
planner's centripetal bound (which holds the car's own lateral acceleration at every offset from the frame's
reference line), and the same for highway-env's IDM in the ego's place (``--planners idm``), which bounds no turn:

    python benchmarks/studies/curve_lateral_acceleration.py --out OUT.json [--envs racetrack-v0 ...] [--planners bilevel idm] [--episodes 5] [--duration 20]

One JSON file: per env, planner and seed the steps, the largest ``v^2 / R``, the steps above the bound and the
largest speed over the lane's speed limit and the steps over it by more than 0.5 m/s (the lane the car is on at
each step: exit-v0's lanes are limited to 26 m/s in the leftmost lane and 3.4 m/s less in each to its right); written after every episode (a rerun redoes them all).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from upstream_roads import ENVS, make_env  # noqa: E402

OVER_LIMIT = 0.5  # [m/s] a policy step counts as over its lane's speed limit beyond this


def episode(env_id: str, seed: int, samples: int, duration: float, planner: str = "bilevel") -> dict:
    """One episode of ``duration`` [s] through ``driveopt.Controller(planner)``: the turn at every policy step."""
    import driveopt
    from driveopt.config import ProjectionConfig
    from highway_env.road.lane import CircularLane

    env = make_env(env_id, duration)
    try:
        env.reset(seed=seed)
        controller = driveopt.Controller(planner, samples=None if planner == "idm" else samples)
        controller.reset(env, seed=seed)
        sim = env.unwrapped
        turns, over_limit = [], []
        for _ in range(round(duration * sim.config["policy_frequency"])):
            _, _, terminated, truncated, _ = env.step(controller.act(env))
            car = sim.vehicle
            lane = sim.road.network.get_lane(car.lane_index)
            turns.append(car.speed ** 2 / lane.radius if isinstance(lane, CircularLane) else 0.0)
            over_limit.append(car.speed - float(lane.speed_limit))
            if terminated or truncated or car.crashed:
                break
        bound = ProjectionConfig().centripetal_max
        return {"env": env_id, "planner": planner, "seed": seed, "steps": len(turns), "bound": bound, "max_turn": max(turns),
                "steps_above_bound": sum(t > bound * 1.001 for t in turns), "max_over_speed_limit": max(over_limit),
                "steps_over_speed_limit": sum(o > OVER_LIMIT for o in over_limit)}
    finally:
        env.close()


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="JSON file")
    parser.add_argument("--envs", nargs="+", default=["racetrack-v0", "racetrack-oval-v0", "racetrack-large-v0"],
                        choices=sorted(ENVS))
    parser.add_argument("--episodes", type=int, default=5, help="seeds 0.. of each env")
    parser.add_argument("--planners", nargs="+", default=["bilevel"], choices=["bilevel", "idm"],
                        help="idm: highway-env's IDM in the ego's place, which bounds no turn")
    parser.add_argument("--samples", type=int, default=250)
    parser.add_argument("--duration", type=float, default=20.0, help="[s] per episode, as the upstream table's")
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.samples < 1 or not args.duration > 0:
        parser.error("--episodes and --samples must be >= 1, --duration > 0")
    records = []
    for env_id, planner in itertools.product(args.envs, args.planners):
        for seed in range(args.episodes):
            records.append(episode(env_id, seed, args.samples, args.duration, planner))
            r = records[-1]
            print(f"{env_id} {planner} seed {seed}: v^2/R up to {r['max_turn']:.2f} m/s^2, {r['steps_above_bound']} of "
                  f"{r['steps']} steps above {r['bound']:g}, up to {r['max_over_speed_limit']:+.2f} m/s over the limit "
                  f"({r['steps_over_speed_limit']} steps over by more than {OVER_LIMIT:g} m/s)",
                  flush=True)
            args.out.write_text(json.dumps({"command": " ".join(sys.argv), "episodes": records}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
