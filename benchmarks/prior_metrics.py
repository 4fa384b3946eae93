"""Offline metrics of the priors on held-out demonstrations: Gaussian, CVAE and VQ-VAE (issue 14, P2 Fig. 1 in numbers).

    python benchmarks/prior_metrics.py --data HELD.h5 [HELD2.h5 ...] --json out/prior_metrics.json \
        [--cvae-weights FILE] [--vqvae-weights FILE] [--priors gaussian-p1 gaussian cvae vqvae] \
        [--validation 0.1 --seed 0] [--max-rows N] [--samples 250] [--best-of 16] [--planner vqvae]

For every usable row (the rows ``driveopt train`` learns from: feasible plan, more than 3 s before a
collision; with ``--validation F`` only the episodes that ``train`` with the same ``--validation`` and
``--seed`` holds out, otherwise all rows of ``--data``, a held-out file) and every prior, the metrics of
:mod:`driveopt.experiments.prior_metrics`: best of ``--best-of`` (16) [m^2] against the executed expert plan,
how many of ``--samples`` (250) samples project feasibly through ``--planner``'s projection (default
``vqvae``: P2's barrier projection, 100 iterations; the configuration capped at the simulated car's
acceleration and curvature as in closed loop), and how many distinct target lanes they reach. The
problem of a row is rebuilt from its observation (:mod:`driveopt.data.replay`: the 10 neighbours it
records, predicted at constant velocity). Every prior sees the same key per row.

Priors: ``gaussian-p1`` (P1's independent set-points), ``gaussian`` (the ``bilevel`` planner's, half
coherent behaviours), ``cvae`` and ``vqvae`` (a PixelCNN checkpoint); a learned prior without
weights (given, or shipped for the data's lane count) is left out with a notice.

Output: one JSON line per (row, prior) in ``<json>.rows.jsonl``, appended as it goes, and the summary
(:func:`driveopt.experiments.prior_metrics.summarise` per prior) in ``--json``, rewritten after every row. A rerun
of the same command skips what is done; a rerun with other settings or data is refused.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import jax
import numpy as np
from tqdm import tqdm

from driveopt.data.demonstrations import load_demonstrations
from driveopt.data.replay import problem_from_row
from driveopt.drivers.optimiser import adapt_to_vehicle
from driveopt.errors import DriveoptError
from driveopt.experiments.prior_metrics import (
    BEST_OF,
    FEASIBILITY_SAMPLES,
    RowMetrics,
    evaluation_config,
    row_metrics,
    summarise,
)
from driveopt.experiments.rows_file import resume_rows, row_line
from driveopt.files import file_digest, write_json
from driveopt.priors import cvae, vqvae
from driveopt.registry import get_optimiser
from driveopt.sampler import GaussianPrior
from driveopt.sim.control import BicycleModel
from driveopt.sim.scenarios import get_scenario
from driveopt.training.cvae import evaluation_road_rows

PRIORS = ("gaussian-p1", "gaussian", "cvae", "vqvae")


class MetricsRunError(DriveoptError):
    """Options, data or an existing results file that this run cannot use."""


def make_priors(names: list[str], config, lanes: int, cvae_weights: str | None,
                vqvae_weights: str | None) -> tuple[dict[str, Any], dict[str, str]]:
    """(name -> prior, name -> digest of its weights file): learned priors from the given or shipped weights, left out
    with a notice without."""
    v_max = config.projection.v_max
    gaussian = GaussianPrior.from_config(config.sampler, v_max)
    priors: dict[str, Any] = {}
    digests: dict[str, str] = {}
    for name in names:
        if name == "gaussian-p1":
            priors[name] = GaussianPrior(gaussian.speed_std, gaussian.lateral_std, v_max, 0.0)
        elif name == "gaussian":
            priors[name] = gaussian
        else:
            module, given = (cvae, cvae_weights) if name == "cvae" else (vqvae, vqvae_weights)
            path = Path(given) if given else module.shipped_weights(lanes)
            if path is None:
                print(f"prior_metrics: no {name} weights shipped for {lanes}-lane roads (pass --{name}-weights): left out",
                      file=sys.stderr)
                continue
            priors[name] = module.load_prior(path, v_max, lanes=lanes)
            digests[name] = file_digest(path)
    return priors, digests


def read_rows(path: Path, settings: dict[str, Any]) -> dict[tuple[str, int], RowMetrics]:
    """Finished (prior, row) results of an earlier run with the same settings (:func:`resume_rows`)."""
    def parse(record: dict[str, Any]) -> tuple[tuple[str, int], RowMetrics]:
        return (record["prior"], record["row"]), RowMetrics(*(record[f] for f in RowMetrics._fields))

    return dict(resume_rows(path, settings, parse, MetricsRunError, "prior_metrics"))


def report(settings: dict[str, Any], priors: list[str], done: dict[tuple[str, int], RowMetrics]) -> dict[str, Any]:
    results = {}
    for name in priors:
        rows = [m for (prior, _), m in done.items() if prior == name]
        if rows:
            results[name] = summarise(rows)
    return {"settings": settings, "results": results}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", nargs="+", required=True, help="demonstrations (HDF5) of one road, from driveopt collect")
    parser.add_argument("--json", default="out/prior_metrics.json", help="summary; per-row results go to <json>.rows.jsonl")
    parser.add_argument("--cvae-weights", help="CVAE checkpoint (default: the shipped weights for the data's road)")
    parser.add_argument("--vqvae-weights", help="PixelCNN checkpoint (default: the shipped weights for the data's road)")
    parser.add_argument("--priors", nargs="+", choices=PRIORS, default=list(PRIORS))
    parser.add_argument("--planner", default="vqvae", help="optimiser whose projection and tolerance decide feasibility")
    parser.add_argument("--validation", type=float, default=0.0, help="evaluate the episodes train holds out with this fraction")
    parser.add_argument("--seed", type=int, default=0, help="the split's seed (as train's) and the sampling seed")
    parser.add_argument("--max-rows", type=int, default=0, help="evaluate at most this many evenly spaced rows (0: all)")
    parser.add_argument("--samples", type=int, default=FEASIBILITY_SAMPLES)
    parser.add_argument("--best-of", type=int, default=BEST_OF)
    args = parser.parse_args(argv)
    if not 0.0 <= args.validation < 1.0 or args.seed < 0 or args.max_rows < 0 or args.samples < 1 or args.best_of < 1:
        parser.error("--validation must be in [0, 1), --seed and --max-rows >= 0, --samples and --best-of >= 1")
    try:
        return run(args)
    except DriveoptError as exc:
        print(f"prior_metrics: error: {exc}", file=sys.stderr)
        return 2


def run(args: argparse.Namespace) -> int:
    data = load_demonstrations(args.data)
    rows, lanes = evaluation_road_rows(data, args.validation, args.seed, args.max_rows, "the learned priors are")
    spec = get_optimiser(args.planner)
    scenarios = {str(name): get_scenario(str(name)) for name in np.unique(data.episodes["scenario"][data.episode[rows]])}
    configs = {name: evaluation_config(adapt_to_vehicle(spec.config, BicycleModel(acceleration_range=s.acceleration_range, steering_range=s.steering_range)), args.samples) for name, s in scenarios.items()}
    priors, weights = make_priors(args.priors, spec.config, lanes, args.cvae_weights, args.vqvae_weights)
    settings = {"data": data.fingerprint(), "rows": len(rows), "validation": args.validation, "seed": args.seed,
                "max_rows": args.max_rows, "samples": args.samples, "best_of": args.best_of, "planner": args.planner,
                "priors": list(priors), "weights": weights}
    summary_path = Path(args.json)
    rows_path = summary_path.with_name(summary_path.stem + ".rows.jsonl")
    summary_path.parent.mkdir(parents=True, exist_ok=True)
    done = read_rows(rows_path, settings)
    base_key = jax.random.PRNGKey(args.seed)
    names = list(priors)
    todo = [int(r) for r in rows if any((name, int(r)) not in done for name in names)]
    bar = tqdm(todo, desc="prior metrics", unit="row", initial=len(rows) - len(todo), total=len(rows))
    with rows_path.open("a") as out:
        for row in bar:
            scenario_name = str(data.episodes["scenario"][data.episode[row]])
            config = configs[scenario_name]
            problem = problem_from_row(data, row, scenarios[scenario_name].v_des, config.basis)
            key = jax.random.fold_in(base_key, row)  # the same draws for every prior of a row
            for name in names:
                if (name, row) in done:
                    continue
                metrics = row_metrics(priors[name], problem, data.trajectory[row], config, key, args.best_of)
                done[(name, row)] = metrics
                out.write(row_line({"prior": name, "row": row, **metrics._asdict()}))
                out.flush()
            write_json(summary_path, report(settings, names, done))
            bar.set_postfix_str(" ".join(f"{n}: {100 * s['feasible_share']:.0f}%"
                                         for n, s in report(settings, names, done)["results"].items()))
    final = report(settings, names, done)
    write_json(summary_path, final)
    for name, stats in final["results"].items():
        print(f"{name:>12}: {stats['rows']} rows, best of {args.best_of} {stats['best_of_n_median']:.1f} m^2 (median), "
              f"a feasible sample in {100 * stats['feasible_share']:.0f}% of rows, "
              f"{stats['lanes_median']:.0f} lanes (median; {stats['feasible_lanes_median']:.0f} among feasible plans)")
    print(f"wrote {summary_path} and {rows_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
