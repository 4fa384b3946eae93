"""Plot of one planning call in the style of P1 Fig. 2(c,d) and Fig. 6.

Rows: the first and the last sampler iteration, each as set-point-QP samples
(left) and the same samples after projection (right), with lane lines, the
neighbours now (boxes) and their predicted paths; the chosen trajectory; and the
per-iteration cost and residual.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from driveopt.config import PlannerConfig
from driveopt.planner import PlanResult, Snapshot
from driveopt.qp import make_model
from driveopt.scene import Scene
from driveopt.viz import figures

MAX_DRAWN = 150  # trajectories per panel


def draw_road(ax, scene: Scene, x_range: tuple[float, float]) -> None:
    lo, hi = scene.road.edges
    for k in range(scene.road.num_lanes + 1):
        y = lo + k * scene.road.lane_width
        style = "-" if k in (0, scene.road.num_lanes) else "--"
        ax.plot(x_range, [y, y], style, color="0.4", lw=1.0, zorder=1)


def draw_vehicles(ax, scene: Scene, horizon: float) -> None:
    t = np.linspace(0.0, horizon, 16)
    for n in scene.neighbours:
        ax.add_patch(Rectangle((n.x - n.length / 2, n.y - n.width / 2), n.length, n.width, color="tab:red", alpha=0.8, zorder=4))
        ax.plot(n.x + n.vx * t, n.y + n.vy * t, ":", color="tab:red", lw=1.0, zorder=3)
    e = scene.ego
    ax.add_patch(Rectangle((e.x - e.length / 2, e.y - e.width / 2), e.length, e.width, color="tab:blue", zorder=5))


def _draw_batch(ax, W: np.ndarray, coeffs: np.ndarray, x0: float, color: str, highlight: np.ndarray | None = None) -> None:
    n = coeffs.shape[1] // 2
    idx = np.linspace(0, coeffs.shape[0] - 1, min(MAX_DRAWN, coeffs.shape[0])).astype(int)
    xs = coeffs[idx, :n] @ W.T + x0
    ys = coeffs[idx, n:] @ W.T
    ax.plot(xs.T, ys.T, color=color, lw=0.5, alpha=0.35, zorder=2)
    if highlight is not None:
        xs = coeffs[highlight, :n] @ W.T + x0
        ys = coeffs[highlight, n:] @ W.T
        ax.plot(xs.T, ys.T, color="tab:orange", lw=0.8, alpha=0.7, zorder=2)


def plot_plan(result: PlanResult, scene: Scene, config: PlannerConfig, path: str | Path) -> Path:
    """Write the figure to ``path`` (PNG/PDF/SVG by extension), whole or not at all, and return the path."""
    model = make_model(config.basis, config.qp)
    W = np.asarray(model.W)
    x0 = result.x_offset
    traj = result.trajectory
    x_max = max(float(np.max(traj.x)), *(float(np.max(s.projected_coeffs[:, : W.shape[1]] @ W[-1:].T)) + x0 for s in (result.first, result.last)))
    x_range = (x0 - 20.0, min(x_max, x0 + 400.0) + 10.0)
    lo, hi = scene.road.edges

    fig = plt.figure(figsize=(14, 11))
    grid = fig.add_gridspec(3, 2, height_ratios=[1, 1, 0.9])
    snaps: list[tuple[str, Snapshot]] = [("first iteration", result.first), ("last iteration", result.last)]
    for row, (label, snap) in enumerate(snaps):
        for col, (kind, coeffs) in enumerate((("set-point QP samples", snap.qp_coeffs), ("projected", snap.projected_coeffs))):
            ax = fig.add_subplot(grid[row, col])
            draw_road(ax, scene, x_range)
            _draw_batch(ax, W, np.asarray(coeffs), x0, "tab:green" if col == 0 else "tab:purple",
                        highlight=np.asarray(snap.elite_index) if col == 1 else None)
            draw_vehicles(ax, scene, config.basis.horizon)
            if row == 1 and col == 1:
                ax.plot(traj.x, traj.y, color="black", lw=2.2, zorder=6, label="chosen")
                ax.legend(loc="upper left", fontsize=8)
            ax.set_xlim(*x_range)
            ax.set_ylim(lo - 2.0, hi + 2.0)
            ax.set_title(f"{label}: {kind}" + (" (orange: elites)" if col == 1 else ""), fontsize=10)
            ax.set_xlabel("x [m]")
            ax.set_ylabel("y [m]")

    hist = result.history
    its = np.arange(1, len(hist.best_score) + 1)
    ax = fig.add_subplot(grid[2, 0])
    best = np.where(hist.best_feasible, hist.best_score, np.nan)
    ax.plot(its, best, "o-", label="best cost + residual (feasible)")
    ax.plot(its, hist.elite_cost, "s--", label="mean elite cost + residual")
    ax.set_xlabel("sampler iteration")
    ax.set_ylabel("cost")
    ax.legend(fontsize=8)
    ax.set_title("upper-level cost per iteration", fontsize=10)
    ax = fig.add_subplot(grid[2, 1])
    ax.plot(its, hist.min_residual, "o-", color="tab:red", label="min residual")
    ax.plot(its, hist.median_residual, "s--", color="tab:purple", label="median residual")
    ax.legend(fontsize=8, loc="upper center")

    ax.set_xlabel("sampler iteration")
    ax.set_ylabel("residual")
    ax2 = ax.twinx()
    ax2.plot(its, hist.num_feasible, "^:", color="tab:gray", label="feasible samples")
    ax2.set_ylabel("feasible samples")
    ax.set_title("constraint residual per iteration", fontsize=10)
    fig.suptitle(f"{scene.name}: {result.status.name} ({result.message})", fontsize=11)
    return save_figure(fig, path)


def save_figure(fig, path: str | Path) -> Path:
    """Lay out, write (format by extension, parent folders created) whole and close ``fig``
    (:func:`driveopt.viz.figures.save_figure`)."""
    return figures.save_figure(fig, path)
