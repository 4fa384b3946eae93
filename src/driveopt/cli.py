"""Command-line interface: ``driveopt plan | problems | drive | bench | collect | train | plot-prior | scenarios | planners``.

Errors in user input (unknown problem, malformed file or config) print one line
``driveopt: error: ...`` on stderr and exit with status 2.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from driveopt.bench.store import StoreError
from driveopt.data.demonstrations import DatasetError
from driveopt.config import ConfigError, PlannerConfig, from_dict, to_dict
from driveopt.learned.checkpoint import CheckpointError
from driveopt.problem import ProblemError, Scene, build_problem, builtin_problems, load_scene, scene_to_dict


class UsageError(Exception):
    """A user-facing error: reported on one line, exit status 2."""


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


def _load_config(path: str | None, args: argparse.Namespace) -> PlannerConfig:
    config = from_dict(_config_overrides(path))
    sampler: dict[str, Any] = {}
    if args.samples is not None:
        sampler["num_samples"] = args.samples
        sampler["num_constraint_elites"] = min(config.sampler.num_constraint_elites, args.samples)
        sampler["num_elites"] = min(config.sampler.num_elites, sampler["num_constraint_elites"])
    if args.iterations is not None:
        sampler["num_iterations"] = args.iterations
    sections: dict[str, Any] = {"sampler": sampler} if sampler else {}
    if args.projection_iterations is not None:
        sections["projection"] = {"max_iterations": args.projection_iterations}
    return config.replace(**sections)


def _config_overrides(path: str | None) -> dict[str, Any]:
    """Planner-config overrides from a JSON file (nested sections), checked against the config schema."""
    if not path:
        return {}
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise UsageError(f"cannot read config {path}: {exc}") from None
    from_dict(data)  # unknown sections, keys or bad values: ConfigError
    return data


def _tolist(a: Any) -> Any:
    return np.asarray(a).round(6).tolist()


def plan_report(result, scene, config: PlannerConfig, timing: dict[str, float]) -> dict[str, Any]:
    """The JSON document of ``driveopt plan --json`` (documented in README)."""
    traj = result.trajectory
    keys = ("t", "x", "y", "speed", "heading", "curvature", "acceleration", "vx", "vy")
    return {
        "status": result.status.name,
        "message": result.message,
        "trajectory": {k: _tolist(getattr(traj, k)) for k in keys},
        "fallback": {k: _tolist(getattr(result.fallback, k)) for k in keys},
        "setpoints": {"speed": _tolist(result.setpoints[:4]), "lateral": _tolist(result.setpoints[4:])},
        "residuals": result.residuals,
        "costs": result.costs,
        "iterations": result.iterations,
        "history": {k: _tolist(v) for k, v in result.history._asdict().items()},
        "timing": timing,
        "problem": scene_to_dict(scene),
        "config": to_dict(config),
    }


def cmd_plan(args: argparse.Namespace) -> int:
    import jax

    from driveopt.planner import plan

    scene = load_scene(args.problem)
    config = _load_config(args.config, args)
    problem = build_problem(scene, config.basis, args.max_obstacles)
    key = jax.random.PRNGKey(args.seed)
    start = time.perf_counter()
    result = plan(problem, config, key=key, x_offset=scene.ego.x)
    first = time.perf_counter() - start
    solves = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        plan(problem, config, key=key, x_offset=scene.ego.x)
        solves.append(time.perf_counter() - start)
    solve = float(np.median(solves)) if solves else first
    timing = {"compile_s": max(first - solve, 0.0), "solve_s": solve, "first_call_s": first}
    traj = result.trajectory
    print(f"{scene.name}: {result.status.name} - {result.message}")
    fmt = lambda values: ", ".join(f"{v:.1f}" for v in values)  # noqa: E731
    print(f"  set-points: speed [{fmt(result.setpoints[:4])}] m/s, lateral [{fmt(result.setpoints[4:])}] m")

    print(f"  residual {result.residuals['total']:.4f}, cost {result.costs['total']:.3f}; end speed {traj.speed[-1]:.1f} m/s, end y {traj.y[-1]:.2f} m")
    print(f"  timing: compile {timing['compile_s']:.2f} s, solve {1e3 * solve:.1f} ms (median of {len(solves)})")
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(plan_report(result, scene, config, timing), indent=1))
        print(f"  wrote {path}")
    if args.plot:
        from driveopt.viz.plan_plot import plot_plan

        print(f"  wrote {plot_plan(result, scene, config, args.plot)}")
    return 0


def cmd_drive(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from driveopt.planners import get_planner
    from driveopt.sim.mpc import run_episode
    from driveopt.sim.scenarios import resolve_scenario

    scenario = resolve_scenario(args.scenario, config_file=args.scenario_config)
    if args.duration is not None:
        scenario = scenario.replace(duration=args.duration)
    spec = get_planner(args.planner).with_samples(args.samples).with_weights(args.weights)
    spec = spec.with_overrides(**_config_overrides(args.config))
    steps = int(round(scenario.duration * scenario.policy_frequency))
    with contextlib.ExitStack() as stack:
        bar = stack.enter_context(tqdm(total=steps, desc=f"{scenario.name} / {spec.name}", unit="step"))
        writer = None
        if args.video:
            from driveopt.viz.video import VideoWriter, draw_plan, plan_overlay_arrays

            writer = stack.enter_context(VideoWriter(args.video, fps=scenario.policy_frequency))

        def on_step(env, result, episode) -> None:
            bar.update(1)
            bar.set_postfix(v=f"{episode.speeds[-1]:.1f}", plan_ms=f"{episode.plan_ms[-1]:.0f}" if episode.plan_ms else "-")

        def draw(env, result) -> None:
            """Render the state the plan was made from, before the simulator steps."""
            frame = env.render()
            if result is not None:
                samples, elites, chosen = plan_overlay_arrays(result, spec.config)
                frame = draw_plan(frame, env, samples=samples, elites=elites, chosen=chosen,
                                  fallback=result.status.name != "SUCCESS")
            writer.append(frame)

        episode = run_episode(scenario, spec, args.seed, render=writer is not None, on_step=on_step,
                              before_step=draw if writer is not None else None)
    plan_ms = np.asarray(episode.plan_ms) if episode.plan_ms else np.zeros(1)
    summary = {
        "scenario": scenario.name, "planner": spec.name, "seed": args.seed, "collided": episode.collided,
        "off_road": episode.off_road, "simulated_s": episode.sim_duration, "mean_speed": episode.mean_speed,
        "plan_ms_median": float(np.median(plan_ms)), "plan_ms_p95": float(np.percentile(plan_ms, 95)),
        "sim_wall_s": episode.sim_seconds, "plan_wall_s": episode.plan_seconds, "statuses": dict(episode.statuses),
    }
    print(
        f"{scenario.name} / {spec.name} (seed {args.seed}): collided {episode.collided}, off-road {episode.off_road}, "
        f"{episode.sim_duration:.1f} s simulated, mean speed {episode.mean_speed:.1f} m/s, "
        f"planning {summary['plan_ms_median']:.0f} ms median / {summary['plan_ms_p95']:.0f} ms p95"
    )
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(summary, indent=1))
        print(f"  wrote {args.json}")
    if args.video:
        print(f"  wrote {args.video}")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from driveopt.bench.harness import BenchSpec, run_bench
    from driveopt.planners import get_planner
    from driveopt.sim.scenarios import get_scenario

    for name in args.scenarios:
        get_scenario(name)  # clear error listing the valid names
    for name in args.planners:
        get_planner(name)
    given = (("duration", args.duration), ("samples", args.samples), ("weights", args.weights), ("config", _config_overrides(args.config) or None))
    options = {k: v for k, v in given if v is not None}
    spec = BenchSpec(tuple(args.scenarios), tuple(args.planners), tuple(args.seeds), args.episodes, options)
    rows = run_bench(spec, args.out, workers=args.workers, backend=args.backend)
    from driveopt.bench.summary import markdown_table

    print(markdown_table(rows))
    print(f"wrote {args.out}/episodes.jsonl, summary.csv, summary.md, summary.png")
    return 0


def cmd_collect(args: argparse.Namespace) -> int:
    from driveopt.data.collect import collect, summary_json

    summary = collect(args.out, args.scenarios, seed=args.seed, episodes=args.episodes, samples=args.samples,
                      iterations=args.iterations, duration=args.duration, workers=args.workers)
    print(f"collected {summary['episodes']} episodes ({summary['rows']} rows, {summary['collided']} collided) in "
          f"{summary['wall_seconds']:.0f} s; {summary['skipped']} already in {args.out}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(summary_json(summary))
    return 0


def cmd_train_cvae(args: argparse.Namespace) -> int:
    from driveopt.learned.cvae import CVAEConfig
    from driveopt.learned.train_cvae import TrainConfig, train_cvae

    cfg = CVAEConfig(latent_dim=args.latent, hidden=tuple(args.hidden))
    tcfg = TrainConfig(epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.lr, beta=args.beta,
                       validation_fraction=args.validation, train_episodes=args.train_episodes, seed=args.seed)
    summary = train_cvae(args.data, args.out, cfg, tcfg, validation_paths=args.validation_data)
    last = summary["history"][-1] if summary["history"] else {}
    print(f"trained {summary['epochs']} epochs on {summary['rows']['train']} rows ({summary['rows']['validation']} validation) "
          f"in {summary['seconds']:.0f} s; last train loss {last.get('train_loss', float('nan')):.3f}, "
          f"best validation loss {summary['best_val_loss']:.3f}; weights: {args.out}/cvae.ckpt")
    return 0


def _scene_for(args: argparse.Namespace) -> Scene:
    if not args.scenario:
        return load_scene(args.problem)
    from driveopt.sim.env import make_env
    from driveopt.sim.mpc import plannable_scene
    from driveopt.sim.observation import scene_from_env
    from driveopt.sim.scenarios import get_scenario

    scenario = get_scenario(args.scenario)
    env = make_env(scenario)
    try:
        env.reset(seed=args.seed)
        return plannable_scene(scene_from_env(env, scenario), env)
    finally:
        env.close()


def cmd_plot_prior(args: argparse.Namespace) -> int:
    from driveopt.learned.prior import load_prior, shipped_weights
    from driveopt.sampler import GaussianPrior
    from driveopt.viz.prior_plot import plot_priors

    scene = _scene_for(args)
    config = PlannerConfig()
    weights = args.weights or shipped_weights(scene.road.num_lanes)
    if weights is None:
        raise UsageError(f"no CVAE weights shipped for {scene.road.num_lanes}-lane roads: pass --weights")
    gaussian = GaussianPrior.from_config(config.sampler, config.projection.v_max)
    priors = {"Gaussian (P1's initial distribution)": dataclasses.replace(gaussian, structured_fraction=0.0),
              "Gaussian + coherent behaviours (bilevel planner)": gaussian,
              f"CVAE ({Path(weights).name})": load_prior(weights, config.projection.v_max)}
    print(f"wrote {plot_priors(priors, scene, config, args.out, num=args.samples, seed=args.seed)}")
    return 0


def cmd_scenarios(args: argparse.Namespace) -> int:
    from driveopt.sim.scenarios import get_scenario, list_scenarios

    for name in list_scenarios():
        s = get_scenario(name)
        print(f"{name:22s} {s.road:8s} lanes {s.lanes}  density {s.density:.1f}  limit {s.speed_limit:.0f} m/s  {s.duration:.0f} s")
    return 0


def cmd_planners(args: argparse.Namespace) -> int:
    from driveopt.planners import PLANNERS

    width = max(len(name) for name in PLANNERS)
    for spec in PLANNERS.values():
        print(f"{spec.name:{width}s}  {spec.description}")
    return 0


def cmd_problems(args: argparse.Namespace) -> int:
    for name in builtin_problems():
        scene = load_scene(name)
        print(f"{name}: {len(scene.neighbours)} neighbours, {scene.road.num_lanes} lanes, ego {scene.ego.vx:.0f} m/s")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="driveopt", description="Bi-level motion planning for dense highway traffic.")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("plan", help="plan once on a built-in problem or a problem JSON file")
    p.add_argument("--problem", default="static-blockage", help="built-in name (see `driveopt problems`) or JSON file")
    p.add_argument("--samples", type=_positive_int, help="samples per sampler iteration (default 1000)")
    p.add_argument("--iterations", type=_positive_int, help="sampler iterations (default 5)")
    p.add_argument("--projection-iterations", type=_positive_int, help="projection iterations (default 20)")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed")
    p.add_argument("--config", help="planner config JSON (nested sections: basis, qp, projection, sampler, cost)")
    p.add_argument("--max-obstacles", type=_positive_int, default=10, help="nearest neighbours considered")
    p.add_argument("--repeats", type=int, default=3, help="extra timed calls after the first (compile) call")
    p.add_argument("--json", help="write the result as JSON here")
    p.add_argument("--plot", help="write a plot (PNG) here")
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("problems", help="list built-in problems")
    p.set_defaults(func=cmd_problems)

    p = sub.add_parser("drive", help="drive one closed-loop episode in highway-env (progress, summary, MP4)")
    p.add_argument("--scenario", default="four-lane-d3.0", help="scenario name (see `driveopt scenarios`)")
    p.add_argument("--scenario-config", help="JSON file overriding scenario fields")
    p.add_argument("--planner", default="cvae-mix", help="planner name (see `driveopt planners`)")
    p.add_argument("--weights", help="learned-prior checkpoint (default: the weights shipped for the road)")
    p.add_argument("--seed", type=int, default=42, help="traffic and sampling seed")
    p.add_argument("--duration", type=float, help="episode length [s] (default: the scenario's)")
    p.add_argument("--samples", type=_positive_int, help="samples per sampler iteration")
    p.add_argument("--video", default="out/drive.mp4", help="MP4 path ('' for none)")
    p.add_argument("--json", help="write the episode summary as JSON here")
    p.add_argument("--config", help="planner config overrides, JSON (nested sections, e.g. {\"cost\": {\"consistency\": 1.0}})")
    p.set_defaults(func=cmd_drive)

    p = sub.add_parser("bench", help="scenarios x planners x seeds x episodes; resumable; summary table and plots")
    p.add_argument("--scenarios", nargs="+", default=["four-lane-d3.0", "two-lane-d2.5"])
    p.add_argument("--planners", nargs="+", default=["bilevel", "vanilla", "grid", "random", "batch", "idm"])
    p.add_argument("--seeds", nargs="+", type=int, default=[42])
    p.add_argument("--episodes", type=_positive_int, default=50, help="episodes per scenario, planner and seed")
    p.add_argument("--duration", type=float, help="episode length [s] (default: the scenario's)")
    p.add_argument("--samples", type=_positive_int, help="override the optimisers' samples per iteration (not vanilla's single sample)")
    p.add_argument("--weights", help="learned-prior checkpoint for the cvae planner (default: shipped weights)")
    p.add_argument("--config", help="planner config overrides applied to every optimiser, JSON (nested sections)")
    p.add_argument("--workers", type=_positive_int, help="parallel episodes (default: CPU count)")
    p.add_argument("--backend", choices=["local", "ray"], default="local")
    p.add_argument("--out", default="out/bench", help="output directory (rerun to resume)")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("collect", help="expert demonstrations (bi-level planner, large batch) into an HDF5 file; resumable")
    p.add_argument("--scenarios", nargs="+", default=["four-lane-d3.0", "two-lane-d2.5"])
    p.add_argument("--seed", type=int, default=7, help="traffic seed (keep it apart from evaluation seeds)")
    p.add_argument("--episodes", type=_positive_int, default=10, help="episodes per scenario")
    p.add_argument("--samples", type=_positive_int, default=1000, help="expert samples per sampler iteration")
    p.add_argument("--iterations", type=_positive_int, default=5, help="expert sampler iterations")
    p.add_argument("--duration", type=float, default=50.0, help="episode length [s]")
    p.add_argument("--workers", type=_positive_int, default=1, help="parallel episodes")
    p.add_argument("--out", default="out/demonstrations.h5", help="HDF5 file (rerun to resume)")
    p.add_argument("--json", help="write the collection summary as JSON here")
    p.set_defaults(func=cmd_collect)

    p = sub.add_parser("train", help="train a learned component (cvae); resumable")
    models = p.add_subparsers(dest="model", required=True)
    p = models.add_parser("cvae", help="CVAE warm start (P1 §III-D) from demonstrations of `driveopt collect`")
    p.add_argument("--data", nargs="+", required=True, help="demonstration HDF5 files")
    p.add_argument("--out", required=True, help="output folder (rerun to resume): last.ckpt, cvae.ckpt, history.json")
    p.add_argument("--epochs", type=_positive_int, default=60)
    p.add_argument("--batch-size", type=_positive_int, default=256)
    p.add_argument("--lr", type=float, default=1e-3, help="AdamW learning rate (x0.1 every 20 epochs)")
    p.add_argument("--beta", type=float, default=1.0, help="KL weight after annealing")
    p.add_argument("--latent", type=_positive_int, default=2, help="latent dimension")
    p.add_argument("--hidden", type=_positive_int, nargs="+", default=[256, 256, 256], help="MLP widths")
    p.add_argument("--validation", type=float, default=0.1, help="share of episodes held out for validation")
    p.add_argument("--validation-data", nargs="+", help="hold out these demonstration files instead (--validation unused)")
    p.add_argument("--train-episodes", type=int, default=0,
                   help="learn from only this many of the other episodes (0: all; the held-out ones stay the same)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_train_cvae)

    p = sub.add_parser("plot-prior", help="Gaussian vs CVAE samples for one observation (P1 Fig. 4)")
    p.add_argument("--problem", default="dense-snapshot", help="built-in problem or JSON file")
    p.add_argument("--scenario", help="take the observation from this scenario's first state instead")
    p.add_argument("--seed", type=int, default=0, help="traffic seed (with --scenario) and sampling seed")
    p.add_argument("--weights", help="CVAE checkpoint (default: the weights shipped for the road)")
    p.add_argument("--samples", type=_positive_int, default=200)
    p.add_argument("--out", default="out/prior.png")
    p.set_defaults(func=cmd_plot_prior)

    p = sub.add_parser("scenarios", help="list scenarios")
    p.set_defaults(func=cmd_scenarios)
    p = sub.add_parser("planners", help="list planners")
    p.set_defaults(func=cmd_planners)
    return parser


def _exit_on_sigterm(signum, frame) -> None:
    raise SystemExit(128 + signum)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if threading.current_thread() is threading.main_thread():
        # A terminated long job (collect, train, bench) unwinds like Ctrl-C: files are closed, the
        # finished work is kept, and a rerun resumes.
        signal.signal(signal.SIGTERM, _exit_on_sigterm)
    try:
        return args.func(args)
    except (UsageError, ProblemError, ConfigError, ValueError, StoreError, DatasetError, CheckpointError) as exc:
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"driveopt: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
