"""``driveopt plot-curves``: training curves of the RL baselines (``driveopt train dqn|ppo``) against env steps.

A training folder holds ``curve.csv``, one row per evaluation (:data:`driveopt.training.rl.CURVE_FIELDS`):
``step`` [env steps], ``collision_rate`` [-, fraction of the evaluation episodes that collided],
``mean_return`` [-, undiscounted episode return], ``mean_speed`` [m/s], ... and, once a run has
finished, ``summary.json`` with its ``algo`` and ``scenario`` (the curve's label; the folder's name
without it).

The figure has three panels against training steps [env steps], one line with markers per run: mean
evaluation return, evaluation collision rate [%] and mean speed [m/s].
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import NamedTuple, Sequence

import numpy as np

from driveopt.errors import DriveoptError
from driveopt.files import make_output_folder
from driveopt.viz.figures import figure_suffixes, save_figure

CURVE_FILE = "curve.csv"
SUMMARY_FILE = "summary.json"
# The columns plotted (a subset of driveopt.training.rl.CURVE_FIELDS, not imported: that module loads the RL stack).
COLUMNS = ("step", "collision_rate", "mean_return", "mean_speed")
PANELS = (  # (column, y label, scale), top to bottom
    ("mean_return", "mean evaluation return [-]", 1.0),
    ("collision_rate", "evaluation collision rate [%]", 100.0),
    ("mean_speed", "mean evaluation speed [m/s]", 1.0),
)


class CurveError(DriveoptError):
    """A training folder without a readable ``curve.csv``, or a malformed one."""


class Curve(NamedTuple):
    """One run's evaluations, in the order of ``curve.csv``."""

    label: str  # "<algo> <scenario>" from summary.json, else the folder's name
    steps: np.ndarray  # [env steps] at each evaluation
    collision_rate: np.ndarray  # [-] fraction of the evaluation episodes that collided
    mean_return: np.ndarray  # [-] mean undiscounted return of the evaluation episodes
    mean_speed: np.ndarray  # [m/s] mean speed over the evaluation episodes
    path: Path  # the curve.csv read


def _label(folder: Path) -> str:
    summary = folder / SUMMARY_FILE
    if not summary.is_file():
        return folder.resolve().name
    try:
        data = json.loads(summary.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CurveError(f"{summary}: not a readable JSON file ({exc})") from None
    if isinstance(data, dict) and data.get("algo") and data.get("scenario"):
        return f"{data['algo']} {data['scenario']}"
    return folder.resolve().name


def read_curve(folder: str | Path) -> Curve:
    """The evaluations in ``folder/curve.csv`` (``folder`` may also be the curve.csv itself); :class:`CurveError` if malformed."""
    path = Path(folder)
    if path.is_dir():
        path = path / CURVE_FILE
    if not path.is_file():
        raise CurveError(f"{path}: no such file (expected a `driveopt train` output folder or its {CURVE_FILE})")
    try:
        with path.open(newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            header = reader.fieldnames or []
            missing = [c for c in COLUMNS if c not in header]
            if missing:
                raise CurveError(f"{path}: missing column(s) {', '.join(missing)} (header: {','.join(header) or 'none'})")
            values: dict[str, list[float]] = {c: [] for c in COLUMNS}
            for row in reader:
                for c in COLUMNS:
                    text = row[c]
                    try:
                        value = float(text)
                    except (TypeError, ValueError):
                        value = math.nan
                    if not math.isfinite(value):
                        shown = "missing" if text is None else repr(text)
                        raise CurveError(f"{path}, line {reader.line_num}: {c} is {shown}, not a finite number")
                    values[c].append(value)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise CurveError(f"{path}: cannot be read ({exc})") from None
    if not values["step"]:
        raise CurveError(f"{path}: no evaluation rows yet (only the header)")
    return Curve(_label(path.parent), *(np.array(values[c]) for c in COLUMNS), path=path)


def plot_curves(curves: Sequence[Curve], path: str | Path) -> Path:
    """Three panels (see the module docstring), one line per curve, written whole to ``path`` (PNG/PDF/SVG by
    extension)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not curves:
        raise CurveError("no training curves to plot")
    path = Path(path)
    if path.is_dir():
        raise CurveError(f"{path} is a directory; give a file path for the figure")
    if path.suffix.lower() not in figure_suffixes():
        raise CurveError(f"{path}: expected a figure file ending in .png, .pdf, .svg (or another matplotlib format)")
    make_output_folder(path.parent, CurveError, path.name)
    labels = [c.label for c in curves]
    fig, axes = plt.subplots(len(PANELS), 1, figsize=(7.5, 9.0), sharex=True)
    for curve, label in zip(curves, labels):
        if labels.count(label) > 1:  # two runs of one algorithm on one scenario: tell them apart by folder
            label = f"{label} ({curve.path.parent.name})"
        for ax, (column, _, scale) in zip(axes, PANELS):
            ax.plot(curve.steps, scale * getattr(curve, column), marker="o", ms=3.5, lw=1.3, label=label)
    for ax, (_, ylabel, _) in zip(axes, PANELS):
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
    axes[1].set_ylim(-2.0, 102.0)
    axes[-1].set_xlim(left=0.0)
    axes[-1].set_xlabel("training steps [env steps]")
    axes[0].legend(fontsize=8)
    fig.suptitle("RL baselines: deterministic evaluation episodes during training", fontsize=11)
    return save_figure(fig, path)
