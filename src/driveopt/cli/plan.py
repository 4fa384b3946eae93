"""``driveopt plan`` and ``driveopt problems``: one planning call on a problem file or a built-in problem.

``--json`` and ``--plot`` are checked (a folder that can be written, a figure extension) before anything is planned,
and written whole (strict JSON: a number that is missing, such as the timing of no repeat, is null).
"""

from __future__ import annotations

import argparse
import dataclasses
import time

from driveopt.cli.common import config_overrides, non_negative_int, positive_int, seed, writable_file, write_json


def register(sub) -> None:
    p = sub.add_parser("plan", help="plan once on a built-in problem or a problem JSON file")
    p.add_argument("--problem", default="static-blockage", help="built-in name (see `driveopt problems`) or JSON file")
    p.add_argument("--planner", default="bilevel", help="optimiser whose prior and config to plan with (see `driveopt planners`)")
    p.add_argument("--weights", help="learned-prior checkpoint (default: the weights shipped for the road)")
    p.add_argument("--filter-weights", help="learned safety-filter checkpoint (vqvae-filter: default the shipped one)")
    p.add_argument("--samples", type=positive_int, help="samples per sampler iteration (default: the planner's)")
    p.add_argument("--iterations", type=positive_int, help="sampler iterations (default: the planner's)")
    p.add_argument("--projection-iterations", type=non_negative_int,
                   help="projection iterations (default: the planner's; 0: samples ranked unprojected)")
    p.add_argument("--seed", type=seed, default=0, help="PRNG seed")
    p.add_argument("--config", help="planner config JSON (nested sections: basis, qp, projection, sampler, cost)")
    p.add_argument("--max-obstacles", type=positive_int, default=10,
                   help="nearest neighbours considered (at most 100, the compile limit, unless DRIVEOPT_ALLOW_LARGE=1)")
    p.add_argument("--repeats", type=non_negative_int, default=3, help="extra timed calls after the first (compile) call; 0: none")
    p.add_argument("--json", help="write the result as JSON here")
    p.add_argument("--plot", help="write a plot here (PNG, or PDF/SVG/... by extension)")
    p.set_defaults(func=run)

    p = sub.add_parser("problems", help="list built-in problems")
    p.set_defaults(func=run_problems)


def _spec(args: argparse.Namespace):
    """The planner's spec with the config file, --samples, --iterations and --projection-iterations applied; WeightsError
    for weights that are not a file or that the planner takes no use of."""
    from driveopt.drivers.base import check_given_weights, with_samples_and_config
    from driveopt.registry import get_optimiser

    spec = get_optimiser(args.planner)
    check_given_weights(spec, args.weights, args.filter_weights)
    spec = with_samples_and_config(spec.with_weights(args.weights), args.samples,
                                   config_overrides(args.config, args.filter_weights))
    check_given_weights(spec, filter_weights=spec.filter_weights)  # or the --config file's safety_filter section
    if args.iterations is not None:
        spec = spec.with_overrides(sampler={"num_iterations": args.iterations})
    if args.projection_iterations is not None:
        spec = spec.with_overrides(projection={"max_iterations": args.projection_iterations})
    return spec


def run(args: argparse.Namespace) -> int:
    import jax
    import numpy as np

    from driveopt.config import check_planning_size, to_dict
    from driveopt.planner import plan
    from driveopt.problem import build_problem
    from driveopt.scene import load_scene, scene_to_dict

    writable_file(args.json, "--json")
    if args.plot:
        from driveopt.viz.figures import figure_suffixes

        writable_file(args.plot, "--plot", figure_suffixes())
    scene = load_scene(args.problem)
    spec = _spec(args)
    config = spec.config
    check_planning_size(config, args.max_obstacles)  # refused in one line before the prior is loaded or anything compiles
    prior = spec.prior(scene.road.num_lanes)
    safety_filter = spec.safety_filter(scene.road.num_lanes)
    problem = build_problem(scene, config.basis, args.max_obstacles, braking_time=spec.braking_time,
                            selection_time=spec.selection_time)
    key = jax.random.PRNGKey(args.seed)
    # one line while the first call compiles (stdout: stderr holds only warnings and errors)
    print(f"compiling {spec.name} ({config.sampler.num_samples} samples) and planning once ...", end=" ", flush=True)
    start = time.perf_counter()
    result = plan(problem, config, key=key, prior=prior, safety_filter=safety_filter, x_offset=scene.ego.x, method=spec.method)
    first = time.perf_counter() - start
    print(f"{first:.1f} s", flush=True)
    solves = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        plan(problem, config, key=key, prior=prior, safety_filter=safety_filter, x_offset=scene.ego.x, method=spec.method)
        solves.append(time.perf_counter() - start)
    solve = float(np.median(solves)) if solves else None
    timing = {"compile_s": None if solve is None else max(first - solve, 0.0), "solve_s": solve, "first_call_s": first}
    traj = result.trajectory
    print(f"{scene.name} / {spec.name}: {result.status.name} - {result.message}")
    fmt = lambda values: ", ".join(f"{v:.1f}" for v in values)  # noqa: E731
    print(f"  set-points: speed [{fmt(result.setpoints[:4])}] m/s, lateral [{fmt(result.setpoints[4:])}] m")
    print(f"  residual {result.residuals['total']:.4f}, cost {result.costs['total']:.3f}; end speed {traj.speed[-1]:.1f} m/s, end y {traj.y[-1]:.2f} m")
    if solve is None:
        print(f"  timing: first call {first:.2f} s (compilation included; --repeats 0 times no further call)")
    else:
        print(f"  timing: compile {timing['compile_s']:.2f} s, solve {1e3 * solve:.1f} ms (median of {len(solves)})")
    if args.json:
        method = {f.name: {"type": type(s).__name__, **dataclasses.asdict(s)}
                  for f in dataclasses.fields(spec.method) for s in [getattr(spec.method, f.name)]}
        report = {**result.to_json(), "timing": timing, "problem": scene_to_dict(scene), "planner": spec.name,
                  "config": to_dict(config), "method": method}
        print(f"  wrote {write_json(args.json, report)}")
    if args.plot:
        from driveopt.viz.plan_plot import plot_plan

        print(f"  wrote {plot_plan(result, scene, config, args.plot)}")
    return 0


def run_problems(args: argparse.Namespace) -> int:
    from driveopt.scene import builtin_problems, load_scene

    for name in builtin_problems():
        scene = load_scene(name)
        print(f"{name}: {len(scene.neighbours)} neighbours, {scene.road.num_lanes} lanes, ego {scene.ego.vx:.0f} m/s")
    return 0
