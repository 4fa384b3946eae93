"""The ego's lane, speed and its two nearest cars every second of one upstream episode (argv: env, reset, planner)."""
import sys, os
os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
from benchmarks.studies.upstream_roads import make_env
import driveopt
env_id, seed, planner = sys.argv[1], int(sys.argv[2]), sys.argv[3]
env = make_env(env_id, 20.0); env.reset(seed=seed)
c = driveopt.Controller(planner); c.reset(env, seed=seed)
sim = env.unwrapped
for step in range(round(20 * sim.config["policy_frequency"])):
    a = c.act(env); _, _, term, trunc, _ = env.step(a)
    v = sim.vehicle
    if step % 5 == 0:
        near = sorted(sim.road.vehicles[1:], key=lambda o: ((o.position - v.position)**2).sum())[:2]
        print(round(sim.time,1), v.lane_index, round(v.speed,2), [(o.lane_index[2], o.lane_index[:2], round(float(((o.position-v.position)**2).sum()**.5),1), round(o.speed,1)) for o in near])
    if term or trunc: break
