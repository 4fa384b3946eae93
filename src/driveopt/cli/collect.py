"""``driveopt collect``: expert demonstrations into an HDF5 file, resumable.

The options and the ``--json`` path are checked (:func:`driveopt.experiments.collect.check_options`,
:func:`driveopt.files.check_output_file`) before the file is created or opened; the summary is strict JSON, written
whole. A write of the file that fails (a full disk) is one line, and leaves the file as it was before that episode
(:mod:`driveopt.data.demonstrations`), so a rerun resumes.
"""

from __future__ import annotations

import argparse

from driveopt.cli.common import positive_int, seed, writable_file, write_json
from driveopt.cli.parser import duration


def register(sub) -> None:
    p = sub.add_parser("collect", help="expert demonstrations (bi-level planner, large batch) into an HDF5 file; resumable")
    p.add_argument("--scenarios", nargs="+", default=["four-lane-d3.0", "two-lane-d2.5"],
                   help="scenario names (see `driveopt scenarios`)")
    p.add_argument("--seed", type=seed, default=7,
                   help="traffic seed s (keep it apart from evaluation seeds; episode e drives traffic seed s x 100003 + e, "
                        "which must fit in 32 bits)")
    p.add_argument("--episodes", type=positive_int, default=10, help="episodes per scenario")
    p.add_argument("--samples", type=positive_int, default=250, help="expert samples per sampler iteration (250, the shipped demonstrations' setting: with 1000 the expert crashed more)")
    p.add_argument("--iterations", type=positive_int, default=5, help="expert sampler iterations")
    p.add_argument("--duration", type=duration, default=50.0, help="episode length [s]")
    p.add_argument("--workers", type=positive_int, default=1, help="parallel episodes")
    p.add_argument("--modes", type=positive_int, default=8,
                   help="distinct feasible plans of the expert's first and final batches stored per step (VQ-VAE training)")
    p.add_argument("--out", default="out/demonstrations.h5", help="HDF5 file (rerun to resume)")
    p.add_argument("--json", help="write the collection summary as JSON here")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from driveopt.experiments.collect import collect

    writable_file(args.json, "--json")
    summary = collect(args.out, args.scenarios, seed=args.seed, episodes=args.episodes, samples=args.samples,
                      iterations=args.iterations, duration=args.duration, workers=args.workers, modes=args.modes)
    print(f"collected {summary['episodes']} episodes ({summary['rows']} rows, {summary['collided']} collided) in "
          f"{summary['wall_seconds']:.0f} s; {summary['skipped']} already in {args.out}")
    if summary["rows"]:
        spread = ", ".join(f"{k}: {n}" for k, n in summary["modes_per_row"].items() if n)
        print(f"modes per row (modes: rows) of the new rows: {spread}")
    if args.json:
        print(f"wrote {write_json(args.json, summary)}")
    return 0
