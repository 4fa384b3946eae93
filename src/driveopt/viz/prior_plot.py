"""``driveopt plot-prior``: for one observation, set-point-QP trajectories of Gaussian samples beside
those of CVAE samples (P1 Fig. 4), with the lane lines, the neighbours and their predicted paths.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import numpy as np

from driveopt.config import PlannerConfig
from driveopt.problem import build_problem
from driveopt.qp import make_model, qp_layer
from driveopt.scene import Scene
from driveopt.viz.plan_plot import draw_road, draw_vehicles, plt, save_figure


def prior_trajectories(prior: Any, scene: Scene, config: PlannerConfig, num: int, key: jax.Array) -> np.ndarray:
    """(num, K, 2) [m] road-frame positions of the set-point-QP trajectories of ``num`` proposals."""
    problem = build_problem(scene, config.basis)
    proposal = prior.propose(problem, key, num, None)
    _, positions = qp_layer(make_model(config.basis, config.qp), config.qp, proposal.samples, problem.init_x, problem.init_y)
    return np.asarray(positions) + np.array([scene.ego.x, 0.0])


def plot_priors(priors: dict[str, Any], scene: Scene, config: PlannerConfig, path: str | Path, num: int = 200, seed: int = 0) -> Path:
    """One panel per named prior, same observation and key; written to ``path`` (PNG/PDF/SVG)."""
    key = jax.random.PRNGKey(seed)
    batches = {name: prior_trajectories(prior, scene, config, num, key) for name, prior in priors.items()}
    x_hi = max(float(np.percentile(b[:, -1, 0], 95)) for b in batches.values())
    x_range = (scene.ego.x - 30.0, min(x_hi, scene.ego.x + 400.0) + 10.0)
    lo, hi = scene.road.edges
    fig, axes = plt.subplots(len(batches), 1, figsize=(12, 3.2 * len(batches)), squeeze=False)
    for ax, (name, positions) in zip(axes[:, 0], batches.items()):
        draw_road(ax, scene, x_range)
        ax.plot(positions[..., 0].T, positions[..., 1].T, color="tab:green", lw=0.5, alpha=0.35, zorder=2)
        draw_vehicles(ax, scene, config.basis.horizon)
        ax.set_xlim(*x_range)
        ax.set_ylim(lo - 2.0, hi + 2.0)
        ax.set_title(f"{name}: {num} samples through the set-point QP", fontsize=10)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    fig.suptitle(f"{scene.name}: ego {scene.ego.vx:.1f} m/s, {len(scene.neighbours)} neighbours", fontsize=11)
    return save_figure(fig, path)
