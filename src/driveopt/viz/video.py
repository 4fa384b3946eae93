"""MP4 videos of closed-loop episodes: plans drawn over highway-env's own frames.

``env.render()`` returns upstream's simulation surface (``viewer.sim_surface``), whose pixel of a
world point (x, y) [m] is ``(p - origin) * scaling``; the road frame of a straight highway is the
world frame. Samples are drawn thin and translucent, elites in orange, the chosen trajectory
thick (green, or red when it is the fallback).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from driveopt.config import PlannerConfig
from driveopt.qp import make_model

SAMPLE_RGBA = (40, 90, 230, 110)
ELITE_RGBA = (255, 150, 0, 170)
CHOSEN_RGBA = (0, 200, 80, 255)
FALLBACK_RGBA = (230, 40, 40, 255)


def world_to_pixel(env: Any, xy: np.ndarray) -> np.ndarray:
    """Pixel coordinates (..., 2) of world points xy (..., 2) [m] in the last rendered frame."""
    viewer = getattr(env.unwrapped, "viewer", None)
    if viewer is None:
        raise RuntimeError("render the env (render_mode='rgb_array') before mapping to pixels")
    surface = viewer.sim_surface
    return (np.asarray(xy, float) - np.asarray(surface.origin, float)) * float(surface.scaling)


def _polyline(draw: ImageDraw.ImageDraw, points: np.ndarray, rgba: tuple, width: int, size: tuple[int, int]) -> None:
    """Draw the part of a pixel polyline that lies near the frame (far-off points are dropped)."""
    w, h = size
    inside = (points[:, 0] > -w) & (points[:, 0] < 2 * w) & (points[:, 1] > -h) & (points[:, 1] < 2 * h)
    pts = points[inside]
    if len(pts) >= 2:
        draw.line([tuple(p) for p in pts], fill=rgba, width=width, joint="curve")


def draw_plan(
    frame: np.ndarray,
    env: Any,
    *,
    samples: np.ndarray | None = None,
    elites: np.ndarray | None = None,
    chosen: np.ndarray | None = None,
    fallback: bool = False,
    label: str | None = None,
) -> np.ndarray:
    """A copy of ``frame`` (H, W, 3) uint8 with trajectories (each (K, 2) road-frame xy [m]) drawn on it."""
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError(f"frame must be (H, W, 3) uint8, got {frame.shape} {frame.dtype}")
    base = Image.fromarray(frame).convert("RGBA")
    overlay = Image.new("RGBA", base.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(overlay)
    for group, rgba, width in ((samples, SAMPLE_RGBA, 1), (elites, ELITE_RGBA, 2)):
        for traj in () if group is None else group:
            _polyline(draw, world_to_pixel(env, traj), rgba, width, base.size)
    if chosen is not None:
        _polyline(draw, world_to_pixel(env, chosen), FALLBACK_RGBA if fallback else CHOSEN_RGBA, 4, base.size)
    text = label if label is not None else ("fallback" if fallback else None)
    if text:
        draw.text((6, 4), text, fill=(0, 0, 0, 255))
    return np.asarray(Image.alpha_composite(base, overlay).convert("RGB"))


def plan_overlay_arrays(result: Any, config: PlannerConfig, max_samples: int = 100) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(samples (S, K, 2), elites (E, K, 2), chosen (K, 2)) road-frame xy of a PlanResult's last iteration."""
    W = np.asarray(make_model(config.basis, config.qp).W)
    n = W.shape[1]
    coeffs = np.asarray(result.last.projected_coeffs)

    def xy(c: np.ndarray) -> np.ndarray:
        return np.stack([c[:, :n] @ W.T + result.x_offset, c[:, n:] @ W.T], axis=-1)

    pick = np.linspace(0, len(coeffs) - 1, min(max_samples, len(coeffs))).astype(int)
    chosen = result.safe_trajectory
    return xy(coeffs[pick]), xy(coeffs[np.asarray(result.last.elite_index)]), np.stack([chosen.x, chosen.y], axis=-1)


class VideoWriter:
    """Write frames to an H.264 MP4 as they come (nothing is kept in memory). Use as a context manager."""

    def __init__(self, path: str | Path, fps: float):
        import imageio.v2 as imageio

        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ValueError(f"cannot create the directory of {self.path}: {exc}") from None
        self._writer = imageio.get_writer(str(self.path), fps=fps, codec="libx264", macro_block_size=1, quality=7)
        self._shape: tuple[int, ...] | None = None
        self.frames = 0

    def append(self, frame: np.ndarray) -> None:
        frame = np.asarray(frame)
        if self._shape is None:
            self._shape = frame.shape
        elif frame.shape != self._shape:
            raise ValueError(f"frame shape changed from {self._shape} to {frame.shape}")
        self._writer.append_data(frame)
        self.frames += 1

    def close(self) -> None:
        self._writer.close()

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
