"""``driveopt plot-prior``: Gaussian and learned priors' samples for one observation, with set-point densities
(P1 Fig. 4, P2 Fig. 1).

Columns: P1's Gaussian, the ``bilevel`` planner's Gaussian (half coherent behaviours), then one per learned prior
that is compared offline (:func:`driveopt.learned_kinds.offline_kinds`: the CVAE, the VQ-VAE with its PixelCNN
codes). A learned prior's weights come from its option (``--cvae-weights``, ``--vqvae-weights``, ...) or are the
ones shipped for the road's lane count; with neither, its column is left out with a notice (on stderr and under
the figure's title). A checkpoint that is given but missing,
corrupted or trained for another lane count is an error (exit 2), checked before any sampling.
The default observation, ``slow-leader-four-lane``, has three homotopy classes (follow, change left,
change right), the situation of P2 Fig. 1.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import sys
from pathlib import Path
from typing import Any, Callable

from driveopt.cli.common import UsageError, positive_int, seed, writable_file
from driveopt.learned_kinds import offline_kinds

DEFAULT_PROBLEM = "slow-leader-four-lane"


def register(sub) -> None:
    p = sub.add_parser("plot-prior", help="Gaussian vs CVAE vs VQ-VAE samples and set-point densities for one observation "
                                          "(P1 Fig. 4, P2 Fig. 1)")
    p.add_argument("--problem", default=DEFAULT_PROBLEM, help="built-in problem or JSON file")
    p.add_argument("--scenario", help="take the observation from this scenario's first state instead")
    p.add_argument("--seed", type=seed, default=0, help="traffic seed (with --scenario) and sampling seed")
    for kind in offline_kinds():
        p.add_argument(kind.weights_option, *kind.weights_aliases, dest=kind.weights_dest,
                       help=f"{kind.checkpoint} (default: the weights shipped for the road)")
    p.add_argument("--samples", type=positive_int, default=200, help="samples drawn from each prior")
    p.add_argument("--out", default="out/prior.png", help="figure, PNG/PDF/SVG by extension")
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


def _learned(label: str, option: str, given: str | None, shipped: Path | None, lanes: int,
             load: Callable[[Path], Any], notes: list[str]) -> tuple[str, Any] | None:
    """(column title, prior) from the given checkpoint or the shipped one; None with a notice when there is neither."""
    path = Path(given) if given else shipped
    if path is None:
        notice = f"{label}: no weights shipped for {lanes}-lane roads (pass {option} FILE): column left out"
        print(f"plot-prior: {notice}", file=sys.stderr)
        notes.append(notice)
        return None
    return f"{label} ({path.name})", load(path)


def run(args: argparse.Namespace) -> int:
    from driveopt.config import PlannerConfig
    from driveopt.sampler import GaussianPrior
    from driveopt.viz.prior_plot import ROWS, plot_priors

    writable_file(args.out, "--out")
    kinds = offline_kinds()
    for kind in kinds:
        given = getattr(args, kind.weights_dest)
        if given and not Path(given).is_file():
            raise UsageError(f"{kind.weights_option} {given}: no such file")
    scene = _scene_for(args)
    lanes = scene.road.num_lanes
    config = PlannerConfig()
    v_max = config.projection.v_max
    gaussian = GaussianPrior.from_config(config.sampler, v_max)
    priors: dict[str, Any] = {"Gaussian (P1's initial distribution)": dataclasses.replace(gaussian, structured_fraction=0.0),
                              "Gaussian + coherent behaviours (bilevel planner)": gaussian}
    notes: list[str] = []
    for column in [_learned(kind.title, kind.weights_option, getattr(args, kind.weights_dest), kind.shipped_weights(lanes),
                            lanes, functools.partial(kind.load_prior, v_max=v_max, lanes=lanes), notes)
                   for kind in kinds]:
        if column is not None:
            priors[column[0]] = column[1]
    figure = plot_priors(priors, scene, config, args.out, num=args.samples, seed=args.seed, notes=notes)
    print(f"wrote {figure.path}: {len(figure.columns)} priors ({', '.join(figure.columns)}) x {len(ROWS)} panels "
          f"({', '.join(ROWS)})")
    return 0
