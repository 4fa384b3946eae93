"""bilevel's first batch at the calls of one upstream episode between two times, with a lane to try.

    PYTHONPATH=. python batch_at_state.py ENV RESET FROM_S TO_S LANE_Y

LANE_Y [m]: the lateral set-point (frame d) of the lane to try. A row "aims at" that lane when its last lateral
set-point is nearer LANE_Y than the car's own d. Per call: how many rows aim at it, how many of those are feasible
(residual under the sampler's tolerance), the cheapest of them against the cheapest of the rest; the same call again
from a narrow Gaussian start at that lane (speed set-points 10 m/s), with the residual families of its rows that aim
at the lane. SHORT=D (environment): the curvature preview cut to D metres.
"""
import dataclasses
import os
import sys

import numpy as np

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
from benchmarks.studies.upstream_roads import make_env  # noqa: E402
import driveopt  # noqa: E402
import driveopt.drivers.optimiser as optimiser  # noqa: E402
from driveopt.planner import make_model  # noqa: E402
from driveopt.projection import constraint_residuals  # noqa: E402
from driveopt.sampler import GaussianPrior  # noqa: E402

env_id, reset, t_from, t_to, lane_y = sys.argv[1], int(sys.argv[2]), *map(float, sys.argv[3:6])
plan = optimiser.plan
now = {"t": 0.0}


def batch_line(name, result, problem, tolerance):
    first = result.first
    final_y, residual, cost = np.asarray(first.setpoints)[:, 7], np.asarray(first.residual), np.asarray(first.cost)
    aims = np.abs(final_y - lane_y) < np.abs(final_y - float(problem.init_y[0]))
    ok = residual < tolerance
    cheapest = lambda rows: f"{cost[rows].min():.2f}" if rows.any() else "-"
    print(f"  {name}: {len(final_y)} rows, {aims.sum()} aim at the lane, {(aims & ok).sum()} of them feasible "
          f"({(~aims & ok).sum()} of the rest); cheapest feasible: at the lane {cheapest(aims & ok)}, "
          f"the rest {cheapest(~aims & ok)}")
    return aims


def probe(problem, config, **kw):
    result = plan(problem, config, **kw)
    if t_from <= now["t"] <= t_to:
        start = np.array(result.mean, dtype=float)
        start[:4], start[4:] = 10.0, lane_y
        narrow = GaussianPrior(2.0, 0.3, kw["prior"].v_max, 0.0)
        at_lane = plan(problem, config, **{**kw, "warm_start": start, "prior": narrow})
        tolerance = config.sampler.residual_tolerance
        print(f"t={now['t']:.1f}: chosen {np.round(result.setpoints, 1)}, cost {result.costs['total']:.2f}")
        batch_line("own batch", result, problem, tolerance)
        aims = batch_line("narrow start at the lane", at_lane, problem, tolerance)
        families = constraint_residuals(make_model(config.basis, config.qp), problem, at_lane.first.projected_coeffs,
                                        config.projection)
        print("    its rows at the lane, median residual per family:",
              {k: round(float(np.median(np.asarray(v)[aims])), 3) for k, v in families._asdict().items()})
    return result


optimiser.plan = probe
env = make_env(env_id, 20.0)
env.reset(seed=reset)
controller = driveopt.Controller("bilevel")
controller.reset(env, seed=reset)
if os.environ.get("SHORT"):
    controller.driver.preview = dataclasses.replace(controller.driver.preview, curvature_time=0.0,
                                                    curvature_distance=float(os.environ["SHORT"]))
sim = env.unwrapped
for _ in range(round(t_to * sim.config["policy_frequency"]) + 1):
    now["t"] = sim.time
    _, _, terminated, truncated, _ = env.step(controller.act(env))
    if terminated or truncated:
        break
