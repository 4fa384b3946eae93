"""The projection's velocity and acceleration rows at the nodes (the default) against at the Bernstein control points
(``projection.derivative_bounds = "control_points"``, ``projection.derivative_pieces`` each of ``--pieces``), and
every obstacle's rows against the nearest ``--nearest`` ones' (``projection.nearest_obstacles``; with ``--combine``
also both at once): constraint residuals, the bounds between the nodes, time per call, and whether the planner picks
the same behaviour.

    python benchmarks/perf/derivative_bounds.py --json out/derivative-bounds.json [--pieces 1 2 4 8] [--nearest 3 4]
        [--combine] [--samples 250] [--keys 10] [--iterations 5 10 20] [--calls 15]

For each built-in problem: the batch of ``projection_acceleration.py`` (random set-points, seed 0, ``--samples`` rows)
projected with the default planner's projection (early stop off) plainly and on each side. Recorded per side and
iteration count:
median and p90 over the batch of the constraint residual (``Residuals.total``, measured at the nodes both ways) and of
each family; the largest speed [m/s] and acceleration [m/s^2] of the projected batch on a fine grid (1000 times),
against ``v_max`` and ``a_max``; the share of rows whose control points (on the side's pieces; the plain side's on
the default ``derivative_pieces``) all meet ``v_max`` and ``a_max``; and at
``max(--iterations)`` the milliseconds per call (the median of ``--calls`` calls each, the sides alternating).

Then the default planner at ``--samples`` samples plans each problem with keys 0 .. ``--keys``-1 each way, and with the
plain projection again under keys shifted by 1000 (how much the pick varies with the key alone). A pick's behaviour is
its lanes (the lane whose centre is nearest each lateral set-point) and its four speed set-points; recorded against the
plain pick of the same key: how often all four lanes agree and how often the last one does, the largest speed set-point
difference [m/s], the pick's cost over the plain pick's, and each side's share of SUCCESS; per pick its status,
residual, cost and set-points. Measurement only; the planner's defaults are not changed.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from driveopt.basis import basis_at, derivative_control_points
from driveopt.cli.common import positive_int
from driveopt.config import PlannerConfig
from driveopt.files import write_json
from driveopt.planner import plan
from driveopt.projection import FAMILIES, project
from driveopt.qp import NUM_SEGMENTS, make_model
from driveopt.scene import load_scene
from driveopt.xla import XLA_CPU_COMPILER_OPTIONS, supported_compiler_options

if __package__ in (None, ""):  # run as a file: the repository root on the path, for the package import below
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks.perf.call_profile import machine  # noqa: E402
from benchmarks.perf.projection_acceleration import PROBLEMS, batch, stats  # noqa: E402

FINE = 1000  # times on [0, T] at which the speed and acceleration bounds are checked


def extremes(config: PlannerConfig, coeffs: np.ndarray, pieces: int) -> dict:
    """Largest speed and acceleration magnitude of trajectories (B, 2n) on a fine grid, and the share of rows whose
    velocity and acceleration control points on ``pieces`` pieces all meet v_max and a_max (to 1e-3)."""
    b, p = config.basis, config.projection
    fine = basis_at(b.order, b.horizon, np.linspace(0.0, b.horizon, FINE))
    velocity, acceleration = derivative_control_points(b.order, b.horizon, pieces)
    n = b.order + 1
    c_x, c_y = np.asarray(coeffs, np.float64)[:, :n], np.asarray(coeffs, np.float64)[:, n:]

    def magnitude(matrix):
        return np.hypot(c_x @ matrix.T, c_y @ matrix.T)

    held = (magnitude(velocity).max(1) <= p.v_max + 1e-3) & (magnitude(acceleration).max(1) <= p.a_max + 1e-3)
    return {"max_speed": round(float(magnitude(fine.Wd).max()), 3), "max_acceleration": round(float(magnitude(fine.Wdd).max()), 3),
            "control_points_within_bounds": round(float(held.mean()), 4)}


def lanes(scene, lateral: np.ndarray) -> list[int]:
    centres = scene.road.lane_centers
    return [int(np.argmin(np.abs(centres - y))) for y in lateral]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", type=Path, required=True, help="results file (written after every problem)")
    parser.add_argument("--pieces", type=positive_int, nargs="+", default=[1, 2, 4, 8],
                        help="projection.derivative_pieces of the control-point sides")
    parser.add_argument("--nearest", type=positive_int, nargs="*", default=[],
                        help="projection.nearest_obstacles of the nearest-obstacle sides")
    parser.add_argument("--combine", action="store_true", help="also every --pieces with every --nearest")
    parser.add_argument("--samples", type=positive_int, default=250, help="batch size and the planner's samples")
    parser.add_argument("--iterations", type=positive_int, nargs="+", default=[5, 10, 20], help="projection iterations")
    parser.add_argument("--calls", type=positive_int, default=15, help="timed projection calls per side")
    parser.add_argument("--keys", type=int, default=10, help="planning keys per problem (0: no planning)")
    parser.add_argument("--problems", nargs="+", default=list(PROBLEMS), help="built-in problems")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_compilation_cache", False)

    config = PlannerConfig().with_samples(args.samples)
    model = make_model(config.basis, config.qp)
    plain = dataclasses.replace(config.projection, tolerance=0.0)
    options = supported_compiler_options(XLA_CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else {}
    compiled = {}

    points = {f"control_points/{p}": {"derivative_bounds": "control_points", "derivative_pieces": p} for p in args.pieces}
    nearest = {f"nearest/{k}": {"nearest_obstacles": k} for k in args.nearest}
    settings = {"nodes": {}, **points, **nearest}
    if args.combine:
        settings.update({f"{a}+{b}": {**points[a], **nearest[b]} for a in points for b in nearest})
    SIDES = tuple(settings)

    def run(where, iterations, data):
        if (where, iterations) not in compiled:
            cfg = dataclasses.replace(plain, **settings[where], max_iterations=iterations)
            compiled[where, iterations] = jax.jit(lambda problem, t, bx, by: project(model, problem, t, bx, by, cfg),
                                                  compiler_options=options)
        return compiled[where, iterations](*data)

    planners = {where: config.replace(projection=setting) for where, setting in settings.items()}
    record = {"arguments": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
              "machine": machine(), "load_before": os.getloadavg(), "projection": dataclasses.asdict(plain), "cases": []}
    for name in args.problems:
        data = batch(model, config, name, args.samples)
        case = {"problem": name, "samples": args.samples, "residuals": []}
        for k in args.iterations:
            entry = {"iterations": k}
            for where in SIDES:
                out = run(where, k, data)
                entry[where] = {"total": stats(out.residuals.total),
                                **{family: stats(getattr(out.residuals, family)) for family in FAMILIES},
                                **extremes(config, out.coeffs, settings[where].get("derivative_pieces", plain.derivative_pieces))}
            case["residuals"].append(entry)
        reference = max(args.iterations)
        times = {where: [] for where in SIDES}
        for where in SIDES:
            run(where, reference, data).coeffs.block_until_ready()
        for _ in range(args.calls):
            for where in SIDES:
                start = time.perf_counter()
                run(where, reference, data).coeffs.block_until_ready()
                times[where].append(time.perf_counter() - start)
        case["timing_ms"] = {where: round(1e3 * float(np.median(t)), 3) for where, t in times.items()}

        scene = load_scene(name)
        problem = data[0]
        picks = []
        for key in range(args.keys):
            results = {where: plan(problem, planners[where], key=jax.random.PRNGKey(key)) for where in SIDES}
            results["nodes_other_key"] = plan(problem, planners["nodes"], key=jax.random.PRNGKey(1000 + key))
            pick = {side: {"status": r.status.name, "residual": round(float(r.residuals["total"]), 4),
                           "cost": round(float(r.costs["total"]), 4),
                           "speeds": [round(float(v), 3) for v in r.setpoints[:NUM_SEGMENTS]],
                           "lanes": lanes(scene, np.asarray(r.setpoints[NUM_SEGMENTS:]))} for side, r in results.items()}
            picks.append(pick)
        if picks:
            def agreement(side):
                same_lanes = [p[side]["lanes"] == p["nodes"]["lanes"] for p in picks]
                speed_gap = [max(abs(a - b) for a, b in zip(p[side]["speeds"], p["nodes"]["speeds"])) for p in picks]
                last_lane = [p[side]["lanes"][-1] == p["nodes"]["lanes"][-1] for p in picks]
                cost_ratio = [p[side]["cost"] / p["nodes"]["cost"] for p in picks]
                return {"same_lanes": round(float(np.mean(same_lanes)), 3),
                        "same_last_lane": round(float(np.mean(last_lane)), 3),
                        "cost_ratio_median": round(float(np.median(cost_ratio)), 3),
                        "cost_ratio_max": round(float(np.max(cost_ratio)), 3),
                        "speed_gap_median": round(float(np.median(speed_gap)), 3),
                        "speed_gap_max": round(float(np.max(speed_gap)), 3),
                        "success": round(float(np.mean([p[side]["status"] == "SUCCESS" for p in picks])), 3)}
            case["plans"] = {"keys": args.keys, "success_nodes": round(float(np.mean(
                [p["nodes"]["status"] == "SUCCESS" for p in picks])), 3),
                "against_nodes": {side: agreement(side) for side in (*SIDES[1:], "nodes_other_key")}, "picks": picks}
        case["load"] = os.getloadavg()
        record["cases"].append(case)
        last = case["residuals"][-1]
        line = ", ".join(f"{w} {last[w]['total']['median']:.3f}/{last[w]['total']['p90']:.3f}" for w in SIDES)
        print(f"{name}: k={last['iterations']} residual median/p90 {line}; {case['timing_ms']} ms; plans against the "
              f"plain pick {case.get('plans', {}).get('against_nodes')}; load {case['load'][0]:.2f}", flush=True)
        write_json(args.json, record)
    record["load_after"] = os.getloadavg()
    write_json(args.json, record)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
