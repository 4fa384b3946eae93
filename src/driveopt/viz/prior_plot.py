"""``driveopt plot-prior``: the first batch of every prior for one observation, side by side (P1 Fig. 4, P2 Fig. 1).

One column per prior (same observation, same sampling key):

- top: the set-point-QP trajectories of its samples in the road frame, with the lane lines, the
  neighbours and their predicted (constant-velocity) paths;
- middle: kernel density of its speed set-points v_1..v_4 [m/s] (all four quarters pooled);
- bottom: kernel density of its final lateral set-point y_4 [m], with the lane centres marked.

The density panels of all columns share their x axes, so a collapsed prior (P2: "posterior collapse"
of the CVAE, one narrow peak) and a multi-modal one (one peak per lane) read at a glance; each keeps
its own density scale (a collapsed prior's peak would flatten every other curve).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple, Sequence

import jax
import numpy as np

from driveopt.config import PlannerConfig
from driveopt.experiments.prior_metrics import proposal_positions
from driveopt.problem import build_problem
from driveopt.qp import NUM_SEGMENTS
from driveopt.scene import Scene
from driveopt.viz.kde import gaussian_kde
from driveopt.viz.plan_plot import draw_road, draw_vehicles, plt, save_figure

ROWS = ("trajectories", "speed set-points", "final lateral set-point")  # panels of one column, top to bottom
COLUMN_WIDTH = 5.5  # [in] figure width per prior
FIGURE_HEIGHT = 9.0  # [in]
GRID_POINTS = 400  # [-] density evaluation points per panel


class PriorSamples(NamedTuple):
    """One prior's first batch for one observation."""

    setpoints: np.ndarray  # (num, 8) v_1..v_4 [m/s], y_1..y_4 [m]
    positions: np.ndarray  # (num, K, 2) [m] road-frame x, y of their set-point-QP trajectories


class PriorPlot(NamedTuple):
    """What :func:`plot_priors` wrote."""

    path: Path
    columns: tuple[str, ...]  # prior names, left to right
    panels: int  # axes in the figure: len(columns) x len(ROWS)


def prior_samples(prior: Any, scene: Scene, config: PlannerConfig, num: int, key: jax.Array) -> PriorSamples:
    """``num`` proposals of ``prior`` for ``scene`` and the road-frame positions of their set-point-QP trajectories."""
    problem = build_problem(scene, config.basis)
    setpoints, positions = proposal_positions(prior, problem, key, num, config.basis, config.qp)
    return PriorSamples(np.asarray(setpoints), np.asarray(positions) + np.array([scene.ego.x, 0.0]))


def _density(ax, values: np.ndarray, grid: np.ndarray, colour: str, min_bandwidth: float) -> None:
    density = gaussian_kde(values, grid, min_bandwidth=min_bandwidth)
    ax.fill_between(grid, density, color=colour, alpha=0.3, lw=0)
    ax.plot(grid, density, color=colour, lw=1.2)
    ax.set_ylim(bottom=0.0)


def plot_priors(priors: dict[str, Any], scene: Scene, config: PlannerConfig, path: str | Path, num: int = 200, seed: int = 0,
                notes: Sequence[str] = ()) -> PriorPlot:
    """One column per named prior (see the module docstring), written to ``path`` (PNG/PDF/SVG by extension).

    notes: lines added under the title (e.g. which prior was left out and why).
    """
    key = jax.random.PRNGKey(seed)
    batches = {name: prior_samples(prior, scene, config, num, key) for name, prior in priors.items()}
    x_hi = max(float(np.percentile(b.positions[:, -1, 0], 95)) for b in batches.values())
    x_range = (scene.ego.x - 30.0, min(x_hi, scene.ego.x + 400.0) + 10.0)
    lo, hi = scene.road.edges
    v_max = config.projection.v_max
    speed_grid = np.linspace(0.0, v_max, GRID_POINTS)
    lateral_grid = np.linspace(lo - 1.0, hi + 1.0, GRID_POINTS)
    columns = len(batches)
    fig, axes = plt.subplots(len(ROWS), columns, figsize=(COLUMN_WIDTH * columns, FIGURE_HEIGHT), squeeze=False,
                             gridspec_kw={"height_ratios": [1.4, 1.0, 1.0]})
    for col, (name, batch) in enumerate(batches.items()):
        ax = axes[0, col]
        draw_road(ax, scene, x_range)
        ax.plot(batch.positions[..., 0].T, batch.positions[..., 1].T, color="tab:green", lw=0.5, alpha=0.35, zorder=2)
        draw_vehicles(ax, scene, config.basis.horizon)
        ax.set_xlim(*x_range)
        ax.set_ylim(lo - 2.0, hi + 2.0)
        ax.set_title(f"{name}\n{num} samples through the set-point QP", fontsize=10)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")

        ax = axes[1, col]
        _density(ax, batch.setpoints[:, :NUM_SEGMENTS], speed_grid, "tab:blue", min_bandwidth=0.05)
        ax.axvline(scene.ego.speed, color="0.3", ls=":", lw=1.0, label=f"ego now ({scene.ego.speed:.1f} m/s)")
        ax.set_xlim(speed_grid[0], speed_grid[-1])
        ax.set_xlabel("speed set-points v_1..v_4 [m/s]")
        ax.set_ylabel("density [1/(m/s)]")
        ax.legend(fontsize=8, loc="upper right")

        ax = axes[2, col]
        _density(ax, batch.setpoints[:, -1], lateral_grid, "tab:purple", min_bandwidth=0.02)
        for centre in scene.road.lane_centers:
            ax.axvline(centre, color="0.5", ls="--", lw=0.8)
        ax.axvline(scene.ego.y, color="0.3", ls=":", lw=1.0)
        ax.set_xlim(lateral_grid[0], lateral_grid[-1])
        ax.set_xlabel("final lateral set-point y_4 [m] (dashed: lane centres, dotted: ego)")
        ax.set_ylabel("density [1/m]")
    title = f"{scene.name}: ego {scene.ego.vx:.1f} m/s, {len(scene.neighbours)} neighbours"
    fig.suptitle("\n".join([title, *notes]), fontsize=11)
    return PriorPlot(save_figure(fig, path), tuple(batches), len(fig.axes))
