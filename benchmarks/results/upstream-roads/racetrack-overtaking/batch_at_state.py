"""bilevel's first batch at a state of one upstream episode (argv: env, reset, from [s], to [s], lateral set-point [m] of
the lane to try): rows aiming at that lane, how many feasible, their cheapest cost against the rest; the same call
again with a narrow Gaussian start at that lane. SHORT=D: the curvature preview cut to D metres."""
import sys, os, numpy as np
os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
from benchmarks.studies.upstream_roads import make_env
import driveopt
import driveopt.drivers.optimiser as opt
from driveopt.planner import WarmStart
env_id, seed, t0, t1, lane_y = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]), float(sys.argv[5])
real = opt.plan
state = {"t": 0.0}
def probe(problem, config, **kw):
    r = real(problem, config, **kw)
    if t0 <= state["t"] <= t1:
        ws = kw.get("warm_start")
        m = np.array(r.mean, dtype=float).copy()
        off = kw.get("x_offset", 0.0)
        # lane y in road frame -> problem frame? print both
        m2 = m.copy(); m2[4:] = lane_y; m2[:4] = 10.0
        from driveopt.sampler import GaussianPrior
        pr = GaussianPrior(2.0, 0.3, kw['prior'].v_max, 0.0)
        r2 = real(problem, config, **{**kw, "warm_start": m2, "prior": pr})
        f = lambda r: f"{r.status.name} total={r.costs['total']:.2f} sp={np.round(r.setpoints,1)} " + " ".join(f"{k}={v:.2f}" for k,v in r.costs.items() if k!='total')
        from driveopt.projection import constraint_residuals
        fs = r2.first; sp = np.asarray(fs.setpoints); lane0 = sp[:, 7] < 122.5
        from driveopt.planner import make_model
        model = make_model(config.basis, config.qp)
        if model is not None:
            res = constraint_residuals(model, problem, fs.projected_coeffs, config.projection)
            from driveopt.trajectory import evaluate
            tr = evaluate(model, fs.projected_coeffs); y = np.asarray(tr.y)
            print('  y_lb/ub', float(problem.y_lb), float(problem.y_ub), 'lane0 rows min y median', np.median(y[lane0].min(1)), 'max y median', np.median(y[lane0].max(1)), 'init_y', np.asarray(problem.init_y))
            rr_ = np.asarray(fs.residual); idx = np.where(lane0)[0]; med = idx[np.argsort(rr_[idx])[len(idx)//2]]
            print('  median lane0 row y', np.round(y[med][::8],2), 'sp', np.round(np.asarray(fs.setpoints)[med],1), 'vx', np.round(np.asarray(tr.vx)[med][::8],1))
            print('  lane0 rows residual families (median):', {k: float(np.median(np.asarray(v)[lane0])) for k, v in res._asdict().items()})
        for nm, rr in (("own", r), ("lane", r2)):
            fs = rr.first; sp = np.asarray(fs.setpoints); res = np.asarray(fs.residual); cost = np.asarray(fs.cost)
            lane0 = sp[:, 7] < 122.5
            ok = res < 0.05
            print(f"  {nm} first batch: rows {len(sp)}, lane0 rows {lane0.sum()}, lane0 feasible {(lane0&ok).sum()}, lane1 feasible {(~lane0&ok).sum()}; min cost lane0 {cost[lane0&ok].min() if (lane0&ok).any() else None} lane1 {cost[~lane0&ok].min() if (~lane0&ok).any() else None}; lane0 median residual {np.median(res[lane0]) if lane0.any() else None}")
        print(f"t={state['t']:.1f} mean={np.round(m,1)}\n  own  : {f(r)}\n  lane : {f(r2)}")
    return r
opt.plan = probe
env = make_env(env_id, 20.0); env.reset(seed=seed)
c = driveopt.Controller("bilevel"); c.reset(env, seed=seed)
import dataclasses
if os.environ.get("SHORT"):
    c.driver.preview = dataclasses.replace(c.driver.preview, curvature_time=0.0, curvature_distance=float(os.environ["SHORT"]))
sim = env.unwrapped
for step in range(round(t1 * sim.config["policy_frequency"]) + 1):
    state["t"] = sim.time
    a = c.act(env)
    _, _, term, trunc, info = env.step(a)
    if term or trunc: break
