"""cvae-filter on highway-v0 reset R at time T (the plain pass's episode): the same 1000 samples (same key) through
the plain pass and through 50 accelerated iterations; the plain pass's cheapest feasible rows and their residuals
after the accelerated one."""
import os, sys, numpy as np
os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
from benchmarks.studies.upstream_roads import make_env
import driveopt
import driveopt.drivers.optimiser as opt
seed, at = int(sys.argv[1]), float(sys.argv[2])
real = opt.plan
state = {"t": 0.0, "done": False}
def probe(problem, config, **kw):
    r = real(problem, config, **kw)
    if not state["done"] and state["t"] >= at - 1e-6:
        state["done"] = True
        a4 = config.replace(projection={"anderson_window": 4, "max_iterations": 50})
        r4 = real(problem, a4, **kw)
        tol = config.sampler.residual_tolerance
        sp, sp4 = np.asarray(r.first.setpoints), np.asarray(r4.first.setpoints)
        print("same samples:", np.allclose(sp, sp4))
        res, res4 = np.asarray(r.first.residual), np.asarray(r4.first.residual)
        cost, cost4 = np.asarray(r.first.cost), np.asarray(r4.first.cost)
        print(f"tolerance {tol}; feasible plain {(res < tol).sum()}, accelerated {(res4 < tol).sum()}")
        order = np.argsort(np.where(res < tol, cost, np.inf))[:10]
        print("plain's 10 cheapest feasible rows: cost, residual plain -> accelerated, cost accelerated, speed set-points")
        for i in order:
            print(f"  row {i:4d}: {cost[i]:7.1f}  {res[i]:.4f} -> {res4[i]:.4f}  {cost4[i]:7.1f}  {np.round(sp[i, :4], 1)}")
        print("chosen: plain", r.status.name, round(r.costs['total'], 1), np.round(r.setpoints[:4], 1),
              "| accelerated", r4.status.name, round(r4.costs['total'], 1), np.round(r4.setpoints[:4], 1))
    return r
opt.plan = probe
env = make_env("highway-v0", 20.0); env.reset(seed=seed)
c = driveopt.Controller("cvae-filter"); c.reset(env, seed=seed)
sim = env.unwrapped
while not state["done"]:
    state["t"] = sim.time
    a = c.act(env)
    _, _, term, trunc, _ = env.step(a)
    if term or trunc: break
