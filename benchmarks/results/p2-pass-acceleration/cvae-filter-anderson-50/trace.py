"""cvae-filter on upstream highway-v0, one reset: per decision the car's speed, the chosen speed set-points, the first
batch's feasible rows and the lowest residual; plain pass (default) against 50 accelerated iterations."""
import os, sys, numpy as np
os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
from benchmarks.studies.upstream_roads import make_env
import driveopt
seed, side = int(sys.argv[1]), sys.argv[2]
config = {"projection": {"anderson_window": 4, "max_iterations": 50}} if side == "a4" else None
env = make_env("highway-v0", 20.0); env.reset(seed=seed)
c = driveopt.Controller("cvae-filter", config=config); c.reset(env, seed=seed)
sim = env.unwrapped
for step in range(20):
    a = c.act(env)
    p = c.planned
    if p is not None and p.result is not None:
        r = p.result; res = np.asarray(r.first.residual)
        print(f"t={sim.time:4.1f} v={sim.vehicle.speed:5.2f} v_des={p.scene.v_des:5.2f} {r.status.name} sp_v={np.round(r.setpoints[:4],1)} y={np.round(r.setpoints[4:],1)} feasible={(res < c.driver.config.sampler.residual_tolerance).sum()} min_res={res.min():.3f} speed_cost={r.costs.get('speed', float('nan')):.2f}")
    _, _, term, trunc, _ = env.step(a)
    if term or trunc: break
