"""How well a sample's constraint residual after a few projection iterations predicts its residual at the end: the
question successive halving (dropping the worse rows early) must answer first.

    python benchmarks/perf/early_residual.py --json out/early-residual.json [--samples 250 1000]
        [--early 1 2 3 5 8 10] [--reference 20]

For each built-in problem and batch size, the batch of ``projection_acceleration.py`` (set-point-QP trajectories from
random set-points, seed 0) is projected with the default planner's projection (early stop off) for each ``--early``
count and for ``--reference`` iterations. Per early count:

- ``spearman``: the rank correlation of the per-sample residuals (``Residuals.total``) early and at the reference;
- ``kept_half`` / ``kept_quarter``: the share of the reference's ``num_constraint_elites`` lowest-residual samples
  (the rows the sampler keeps, P1 Alg. 1) that are among the best half / quarter early (1.0: halving at that count
  would have lost none of them; a quarter smaller than the elites is skipped, null).

Measurement only; nothing in the planner changes. The batches are the built-in problems' (no recorded closed-loop
states are stored in the repository), so this answers for those states only.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from pathlib import Path

import jax
import numpy as np
from scipy import stats

if __package__ in (None, ""):  # run as a file: the repository root on the path, for the package import below
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks.perf.call_profile import machine  # noqa: E402
from benchmarks.perf.projection_acceleration import PROBLEMS, batch  # noqa: E402
from driveopt.cli.common import positive_int  # noqa: E402
from driveopt.config import PlannerConfig  # noqa: E402
from driveopt.files import write_json  # noqa: E402
from driveopt.projection import project  # noqa: E402
from driveopt.qp import make_model  # noqa: E402


def kept_share(early: np.ndarray, final: np.ndarray, elites: int, keep: int) -> float | None:
    """The share of the ``elites`` lowest ``final`` residuals whose samples are among the ``keep`` lowest ``early``
    ones; None when ``keep`` < ``elites`` (halving that far cannot keep them all by construction)."""
    if keep < elites:
        return None
    best_final = set(np.argsort(final, kind="stable")[:elites].tolist())
    best_early = set(np.argsort(early, kind="stable")[:keep].tolist())
    return len(best_final & best_early) / elites


def prediction(early: np.ndarray, final: np.ndarray, elites: int) -> dict:
    """Rank correlation of ``early`` and ``final`` residuals and the elites halving would keep."""
    n = len(final)
    return {"spearman": round(float(stats.spearmanr(early, final).statistic), 4),
            "kept_half": kept_share(early, final, elites, n // 2),
            "kept_quarter": kept_share(early, final, elites, n // 4)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", type=Path, required=True, help="results file (written after every case)")
    parser.add_argument("--samples", type=positive_int, nargs="+", default=[250, 1000], help="batch sizes")
    parser.add_argument("--early", type=positive_int, nargs="+", default=[1, 2, 3, 5, 8, 10],
                        help="early iteration counts")
    parser.add_argument("--reference", type=positive_int, default=20, help="the final iteration count")
    parser.add_argument("--problems", nargs="+", default=list(PROBLEMS), help="built-in problems")
    args = parser.parse_args(argv)
    if max(args.early) >= args.reference:
        parser.error(f"--early counts must be below --reference ({args.reference})")

    config = PlannerConfig()
    model = make_model(config.basis, config.qp)
    projection = dataclasses.replace(config.projection, tolerance=0.0)
    compiled = {}

    def residuals(iterations: int, data) -> np.ndarray:
        if iterations not in compiled:
            c = dataclasses.replace(projection, max_iterations=iterations)
            compiled[iterations] = jax.jit(lambda problem, t, bx, by: project(model, problem, t, bx, by, c))
        return np.asarray(compiled[iterations](*data).residuals.total)

    record = {"arguments": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
              "machine": machine(), "load_before": os.getloadavg(), "projection": dataclasses.asdict(projection),
              "cases": []}
    for samples in args.samples:
        elites = config.with_samples(samples).sampler.num_constraint_elites
        for name in args.problems:
            data = batch(model, config, name, samples)
            final = residuals(args.reference, data)
            case = {"problem": name, "samples": samples, "elites": elites, "early": {}}
            for k in args.early:
                case["early"][str(k)] = prediction(residuals(k, data), final, elites)
            record["cases"].append(case)
            write_json(args.json, record)
            print(f"{samples:5d} {name:24s} " + ", ".join(f"k={k}: rho {v['spearman']:.2f} half {v['kept_half']}"
                                                          for k, v in case["early"].items()), flush=True)
    record["load_after"] = os.getloadavg()
    write_json(args.json, record)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
