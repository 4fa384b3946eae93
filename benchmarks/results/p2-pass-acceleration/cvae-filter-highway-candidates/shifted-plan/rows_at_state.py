"""cvae-filter on highway-v0 reset R at time T (the plain pass's episode, P2's 100 plain iterations, the previous plan's
row re-solved from its set-points): the same call's carried row and choice with the row re-solved and with the plan
moved on (ShiftedPlan), through 100 plain, 50 and 20 accelerated iterations.

    PYTHONPATH=. python benchmarks/results/p2-pass-acceleration/shifted-plan/rows_at_state.py 4 3.0
"""
import dataclasses
import os
import sys

import numpy as np

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
from benchmarks.studies.upstream_roads import make_env  # noqa: E402
import driveopt  # noqa: E402
import driveopt.drivers.optimiser as opt  # noqa: E402
from driveopt.carried_row import ResolvedSetpoints, ShiftedPlan  # noqa: E402

seed, at = int(sys.argv[1]), float(sys.argv[2])
real = opt.plan
state = {"t": 0.0, "done": False}


def report(label, result, config):
    row = config.sampler.num_samples  # the carried row follows the samples
    res, cost = np.asarray(result.first.residual), np.asarray(result.first.cost)
    feasible = int((res <= config.sampler.residual_tolerance).sum())
    print(f"  {label:34s} carried row: residual {res[row]:.4f}, cost {cost[row]:6.1f} | {feasible:4d} rows feasible | "
          f"chosen {result.status.name} cost {result.costs['total']:6.1f}, speed set-points {np.round(result.setpoints[:4], 1)}")


def probe(problem, config, **kw):
    result = real(problem, config, **kw)
    if not state["done"] and state["t"] >= at - 1e-6 and bool(kw["previous"].present):
        state["done"] = True
        print(f"highway-v0 reset {seed}, {state['t']:.1f} s, car at {problem.init_x[1]:.1f} m/s")
        passes = (("100 plain", {}), ("50 accelerated", {"anderson_window": 4, "max_iterations": 50}),
                  ("20 accelerated", {"anderson_window": 4, "max_iterations": 20}))
        for row_name, row in (("re-solved", ResolvedSetpoints()), ("moved on", ShiftedPlan())):
            method = dataclasses.replace(kw["method"], carried_row=row)
            for pass_name, projection in passes:
                changed = config.replace(projection=projection)
                report(f"{pass_name}, row {row_name}", real(problem, changed, **{**kw, "method": method}), changed)
    return result


opt.plan = probe
env = make_env("highway-v0", 20.0)
env.reset(seed=seed)
controller = driveopt.Controller("cvae-filter")
controller.reset(env, seed=seed)
while not state["done"]:
    state["t"] = env.unwrapped.time
    _, _, terminated, truncated, _ = env.step(controller.act(env))
    if terminated or truncated:
        break
