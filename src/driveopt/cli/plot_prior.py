"""``driveopt plot-prior``: samples of the Gaussian and learned priors for one observation (P1 Fig. 4)."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from driveopt.cli.common import UsageError, positive_int


def register(sub) -> None:
    p = sub.add_parser("plot-prior", help="Gaussian vs CVAE samples for one observation (P1 Fig. 4)")
    p.add_argument("--problem", default="dense-snapshot", help="built-in problem or JSON file")
    p.add_argument("--scenario", help="take the observation from this scenario's first state instead")
    p.add_argument("--seed", type=int, default=0, help="traffic seed (with --scenario) and sampling seed")
    p.add_argument("--weights", help="CVAE checkpoint (default: the weights shipped for the road)")
    p.add_argument("--samples", type=positive_int, default=200)
    p.add_argument("--out", default="out/prior.png")
    p.set_defaults(func=run)


def _scene_for(args: argparse.Namespace):
    from driveopt.scene import load_scene

    if not args.scenario:
        return load_scene(args.problem)
    from driveopt.sim.env import make_env
    from driveopt.sim.perception import perceive
    from driveopt.sim.scenarios import get_scenario

    scenario = get_scenario(args.scenario)
    env = make_env(scenario)
    try:
        env.reset(seed=args.seed)
        return perceive(env, scenario).scene
    finally:
        env.close()


def run(args: argparse.Namespace) -> int:
    from driveopt.config import PlannerConfig
    from driveopt.priors.cvae import load_prior, shipped_weights
    from driveopt.priors.gaussian import GaussianPrior
    from driveopt.viz.prior_plot import plot_priors

    scene = _scene_for(args)
    config = PlannerConfig()
    weights = args.weights or shipped_weights(scene.road.num_lanes)
    if weights is None:
        raise UsageError(f"no CVAE weights shipped for {scene.road.num_lanes}-lane roads: pass --weights")
    gaussian = GaussianPrior.from_config(config.sampler, config.projection.v_max)
    priors = {"Gaussian (P1's initial distribution)": dataclasses.replace(gaussian, structured_fraction=0.0),
              "Gaussian + coherent behaviours (bilevel planner)": gaussian,
              f"CVAE ({Path(weights).name})": load_prior(weights, config.projection.v_max, lanes=scene.road.num_lanes)}
    print(f"wrote {plot_priors(priors, scene, config, args.out, num=args.samples, seed=args.seed)}")
    return 0
