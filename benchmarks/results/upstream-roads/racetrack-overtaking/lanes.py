"""The ego's lane, speed and its two nearest cars (lane, road, distance [m], speed [m/s]) every second of one upstream
episode: ``PYTHONPATH=. python lanes.py ENV RESET PLANNER`` (a driveopt planner, or ``idm``)."""
import os
import sys

import numpy as np

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
from benchmarks.studies.upstream_roads import make_env  # noqa: E402
import driveopt  # noqa: E402

env_id, reset, planner = sys.argv[1], int(sys.argv[2]), sys.argv[3]
env = make_env(env_id, 20.0)
env.reset(seed=reset)
controller = driveopt.Controller(planner)
controller.reset(env, seed=reset)
sim = env.unwrapped
frequency = int(sim.config["policy_frequency"])
for step in range(20 * frequency):
    _, _, terminated, truncated, _ = env.step(controller.act(env))
    ego = sim.vehicle
    if step % frequency == 0:
        distance = lambda other: float(np.linalg.norm(other.position - ego.position))
        near = sorted((o for o in sim.road.vehicles if o is not ego), key=distance)[:2]
        print(round(sim.time, 1), ego.lane_index, round(ego.speed, 2),
              [(o.lane_index[2], o.lane_index[:2], round(distance(o), 1), round(o.speed, 1)) for o in near])
    if terminated or truncated:
        break
