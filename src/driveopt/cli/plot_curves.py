"""``driveopt plot-curves``: training curves of the RL baselines against env steps.

Reads ``curve.csv`` (and ``summary.json`` for the label) of each ``driveopt train dqn|ppo`` output
folder and draws mean evaluation return, evaluation collision rate [%] and mean speed [m/s] against
training steps, one line per run (:mod:`driveopt.viz.curves`). Every folder is read before anything
is drawn: a missing or malformed ``curve.csv`` is an error (exit 2) naming the file. The figure goes to ``--out``,
by default ``out/rl-curves.png`` under the working directory (never into the repository's tracked figures), and is
written whole; its extension and folder are checked before any curve is read.
"""

from __future__ import annotations

import argparse

from driveopt.cli.common import writable_file

DEFAULT_OUT = "out/rl-curves.png"  # relative to the working directory: an output, never a tracked file


def register(sub) -> None:
    p = sub.add_parser("plot-curves", help="training curves (evaluation return, collision rate, speed) of `driveopt train` runs")
    p.add_argument("runs", nargs="+", metavar="RUN_DIR", help="`driveopt train` output folders (or their curve.csv files)")
    p.add_argument("--out", default=DEFAULT_OUT, help=f"figure, PNG/PDF/SVG by extension (default {DEFAULT_OUT})")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from driveopt.viz.curves import plot_curves, read_curve
    from driveopt.viz.figures import figure_suffixes

    writable_file(args.out, "--out", figure_suffixes())
    curves = [read_curve(folder) for folder in args.runs]
    path = plot_curves(curves, args.out)
    runs = ", ".join(f"{c.label} ({len(c.steps)} evaluation(s), up to step {int(c.steps[-1])})" for c in curves)
    print(f"wrote {path}: {len(curves)} run(s): {runs}")
    return 0
