"""MP4 videos of closed-loop episodes: plans drawn over highway-env's own frames.

``env.render()`` returns upstream's simulation surface (``viewer.sim_surface``), whose pixel of a
world point (x, y) [m] is ``(p - origin) * scaling``; plans are made in the road (Frenet) frame and turned
into world points by the frame they were made in (:func:`plan_overlay_arrays`, any road, curved too).
Samples are drawn thin and translucent, elites in orange, the chosen trajectory thick (green, or red when
it is the fallback); a small legend names the colours, a heads-up box in the top-left corner holds text
lines (:mod:`driveopt.viz.overlay` fills it with time, speeds, planner, status and planning time).

Polylines are clipped segment by segment against the frame (Liang-Barsky, vectorised): a line
that crosses the edge is drawn up to the edge, and one that leaves the frame and comes back is
drawn as separate pieces, never joined across the part that is off screen.
"""

from __future__ import annotations

import contextlib
import os
import struct
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from driveopt.config import PlannerConfig
from driveopt.errors import DriveoptError
from driveopt.files import commit, temporary_sibling
from driveopt.qp import make_model


class VideoError(DriveoptError):
    """A video cannot be recorded here (black-frame SDL driver, unwritable path, a write that failed)."""


VIDEO_SUFFIXES = (".mp4",)  # H.264 in an MP4 container

SAMPLE_RGBA = (40, 90, 230, 110)
ELITE_RGBA = (255, 150, 0, 170)
CHOSEN_RGBA = (0, 200, 80, 255)
FALLBACK_RGBA = (230, 40, 40, 255)
PREDICTED_RGBA = (120, 0, 160, 90)  # neighbours' predicted boxes: faint
SAMPLE_WIDTH, ELITE_WIDTH, CHOSEN_WIDTH, PREDICTED_WIDTH = 1, 2, 4, 1  # [px] stroke widths
LEGEND_BG_RGBA = (255, 255, 255, 190)
HUD_BG_RGBA = (255, 255, 255, 200)
WORLD_NODES = 25  # [-] nodes of each sampled and elite plan drawn in world coordinates (the chosen plan keeps all)
TEXT_RGBA = (0, 0, 0, 255)


def check_video_driver() -> None:
    """Raise VideoError when SDL renders (or will render) with the ``dummy`` driver: its frames are black.

    Looks at SDL_VIDEODRIVER (read whenever pygame's display starts) and, when pygame's display is
    running, at the driver it actually uses.
    """
    drivers = [os.environ.get("SDL_VIDEODRIVER", "")]
    pygame = sys.modules.get("pygame")
    if pygame is not None:
        try:
            if pygame.display.get_init():
                drivers.append(pygame.display.get_driver() or "")
        except Exception:  # pragma: no cover - a pygame without a usable display module
            pass
    if any(d.strip().lower() == "dummy" for d in drivers):
        raise VideoError(
            "SDL video driver is 'dummy', which renders black frames: "
            "set SDL_VIDEODRIVER=offscreen (or leave it unset) to record videos"
        )


def world_to_pixel(env: Any, xy: np.ndarray) -> np.ndarray:
    """Pixel coordinates (..., 2) of world points xy (..., 2) [m] in the last rendered frame."""
    viewer = getattr(env.unwrapped, "viewer", None)
    if viewer is None:
        raise RuntimeError("render the env (render_mode='rgb_array') before mapping to pixels")
    surface = viewer.sim_surface
    return (np.asarray(xy, float) - np.asarray(surface.origin, float)) * float(surface.scaling)


def clip_segments(p0: np.ndarray, p1: np.ndarray, lo: tuple[float, float], hi: tuple[float, float]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Liang-Barsky clipping of segments p0 -> p1 (each (M, 2)) against the box lo <= p <= hi.

    Returns (visible (M,) bool, t0 (M,), t1 (M,)): the part of segment i inside the box is
    ``p0 + t * (p1 - p0)`` for t in [t0, t1] where visible; segments with a non-finite end are not.
    """
    p0 = np.asarray(p0, float).reshape(-1, 2)
    p1 = np.asarray(p1, float).reshape(-1, 2)
    d = p1 - p0
    # the four boundaries x >= lo_x, x <= hi_x, y >= lo_y, y <= hi_y as p * t <= q
    p = np.stack([-d[:, 0], d[:, 0], -d[:, 1], d[:, 1]], axis=1)
    q = np.stack([p0[:, 0] - lo[0], hi[0] - p0[:, 0], p0[:, 1] - lo[1], hi[1] - p0[:, 1]], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = q / p
    entering, leaving, parallel = p < 0, p > 0, p == 0
    t0 = np.max(np.where(entering, t, 0.0), axis=1)
    t1 = np.min(np.where(leaving, t, 1.0), axis=1)
    outside_parallel = np.any(parallel & (q < 0), axis=1)
    finite = np.all(np.isfinite(p0), axis=1) & np.all(np.isfinite(p1), axis=1)
    visible = finite & ~outside_parallel & (t0 <= t1)
    return visible, np.clip(t0, 0.0, 1.0), np.clip(t1, 0.0, 1.0)


def clip_polyline(points: np.ndarray, size: tuple[int, int], margin: float = 0.0) -> list[np.ndarray]:
    """The pieces (each (n >= 2, 2)) of a pixel polyline inside a frame of size (width, height).

    Pixel centres run from 0 to width - 1 (height - 1); the box is grown by ``margin`` pixels on
    every side (half a stroke width keeps the in-frame part of a thick stroke along the edge).
    A segment crossing the box is cut at the box edge; where the polyline leaves the box (or has a
    non-finite point) the piece ends, and it starts a new piece where it comes back.
    """
    pts = np.asarray(points, float).reshape(-1, 2)
    if len(pts) < 2:
        return []
    w, h = size
    lo, hi = (-margin, -margin), (w - 1 + margin, h - 1 + margin)
    a, b = pts[:-1], pts[1:]
    visible, t0, t1 = clip_segments(a, b, lo, hi)
    idx = np.flatnonzero(visible)
    if idx.size == 0:
        return []
    start = a[idx] + t0[idx, None] * (b[idx] - a[idx])
    end = a[idx] + t1[idx, None] * (b[idx] - a[idx])
    # a visible segment continues the previous piece when it directly follows a visible segment,
    # that one reached its end point uncut and this one starts at its own start point uncut
    joined = np.zeros(idx.size, bool)
    joined[1:] = (np.diff(idx) == 1) & (t1[idx[:-1]] >= 1.0) & (t0[idx[1:]] <= 0.0)
    firsts = np.flatnonzero(~joined)
    lasts = np.append(firsts[1:], idx.size)
    return [np.vstack([start[i : i + 1], end[i:j]]) for i, j in zip(firsts, lasts)]


def _polyline(draw: ImageDraw.ImageDraw, points: np.ndarray, rgba: tuple, width: int, size: tuple[int, int]) -> bool:
    """Draw the in-frame pieces of a pixel polyline; True when anything was drawn."""
    pieces = clip_polyline(points, size, margin=width / 2.0)
    for piece in pieces:
        draw.line([tuple(p) for p in piece], fill=rgba, width=width, joint="curve")
    return bool(pieces)


def _font() -> ImageFont.ImageFont:
    return ImageFont.load_default()


def draw_legend(draw: ImageDraw.ImageDraw, entries: list[tuple[str, tuple, int]], size: tuple[int, int]) -> None:
    """A one-row legend (a short line in each colour and its name) in the bottom-right corner."""
    if not entries:
        return
    font = _font()
    pad, swatch, gap, spacing = 3, 12, 3, 8
    widths = [int(np.ceil(draw.textlength(name, font=font))) for name, _, _ in entries]
    left, top, _, bottom = draw.textbbox((0, 0), "Ag", font=font)
    text_h = bottom - top
    row_h = max(text_h, max(w for _, _, w in entries)) + 2 * pad
    total = sum(swatch + gap + w for w in widths) + spacing * (len(entries) - 1) + 2 * pad
    w, h = size
    x0, y0 = max(w - total - 2, 0), max(h - row_h - 2, 0)
    draw.rectangle([x0, y0, x0 + total, y0 + row_h], fill=LEGEND_BG_RGBA)
    x, yc = x0 + pad, y0 + row_h / 2.0
    for (name, rgba, width), tw in zip(entries, widths):
        draw.line([(x, yc), (x + swatch, yc)], fill=rgba[:3] + (255,), width=width)
        x += swatch + gap
        draw.text((x - left, yc - text_h / 2.0 - top), name, fill=TEXT_RGBA, font=font)
        x += tw + spacing


def draw_text_box(draw: ImageDraw.ImageDraw, lines: list[str], size: tuple[int, int]) -> tuple[int, int, int, int]:
    """Text lines on a translucent white box in the top-left corner; the box (x0, y0, x1, y1) [px], clipped to the
    frame of size (width, height)."""
    font = _font()
    pad, spacing = 4, 2
    left, top, _, bottom = draw.textbbox((0, 0), "Ag", font=font)
    line_h = bottom - top
    width = max(int(np.ceil(draw.textlength(line, font=font))) for line in lines) + 2 * pad
    height = len(lines) * line_h + (len(lines) - 1) * spacing + 2 * pad
    box = (2, 2, min(2 + width, size[0] - 1), min(2 + height, size[1] - 1))
    draw.rectangle(box, fill=HUD_BG_RGBA)
    for i, line in enumerate(lines):
        draw.text((2 + pad - left, 2 + pad + i * (line_h + spacing) - top), line, fill=TEXT_RGBA, font=font)
    return box


def draw_plan(
    frame: np.ndarray,
    env: Any,
    *,
    samples: np.ndarray | None = None,
    elites: np.ndarray | None = None,
    chosen: np.ndarray | None = None,
    fallback: bool = False,
    label: str | None = None,
    legend: bool = True,
    hud: list[str] | None = None,
    predicted: np.ndarray | None = None,
) -> np.ndarray:
    """A copy of ``frame`` (H, W, 3) uint8 with trajectories (each (K, 2) world xy [m]) drawn on it.

    With ``legend`` (and anything in view) a legend names the colours of the groups given; ``hud`` lines go in a box
    in the top-left corner (instead of ``label``); ``predicted``: (M, 4, 2) world corners [m] of boxes drawn as faint
    outlines (the neighbours' predicted positions, :func:`driveopt.viz.overlay.predicted_boxes`).
    """
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError(f"frame must be (H, W, 3) uint8, got {frame.shape} {frame.dtype}")
    base = Image.fromarray(frame).convert("RGBA")
    overlay = Image.new("RGBA", base.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(overlay)
    drawn = False
    entries: list[tuple[str, tuple, int]] = []
    boxes = () if predicted is None else predicted
    for box in boxes:
        drawn |= _polyline(draw, world_to_pixel(env, np.vstack([box, box[:1]])), PREDICTED_RGBA, PREDICTED_WIDTH, base.size)
    if len(boxes):
        entries.append(("predicted", PREDICTED_RGBA, 2))
    for name, group, rgba, width in (("sampled", samples, SAMPLE_RGBA, SAMPLE_WIDTH), ("elite", elites, ELITE_RGBA, ELITE_WIDTH)):
        trajs = () if group is None else group
        for traj in trajs:
            drawn |= _polyline(draw, world_to_pixel(env, traj), rgba, width, base.size)
        if len(trajs):
            entries.append((name, rgba, width))
    if chosen is not None:
        drawn |= _polyline(draw, world_to_pixel(env, chosen), FALLBACK_RGBA if fallback else CHOSEN_RGBA, CHOSEN_WIDTH, base.size)
        entries += [("chosen", CHOSEN_RGBA, CHOSEN_WIDTH // 2), ("fallback", FALLBACK_RGBA, CHOSEN_WIDTH // 2)]
    text = label if label is not None else ("fallback" if fallback else None)
    if hud:
        draw_text_box(draw, list(hud), base.size)
    elif text:
        draw.text((6, 4), text, fill=TEXT_RGBA, font=_font())
    if legend and drawn:
        draw_legend(draw, entries, base.size)
    return np.asarray(Image.alpha_composite(base, overlay).convert("RGB"))


def pad_to_even(frame: np.ndarray) -> np.ndarray:
    """``frame`` (H, W, C) with a last row and/or column repeated so H and W are even (H.264 needs that)."""
    frame = np.asarray(frame)
    pad_h, pad_w = frame.shape[0] % 2, frame.shape[1] % 2
    if not (pad_h or pad_w):
        return frame
    return np.pad(frame, ((0, pad_h), (0, pad_w)) + ((0, 0),) * (frame.ndim - 2), mode="edge")


def plan_overlay_arrays(result: Any, config: PlannerConfig, max_samples: int = 100, road_frame: Any = None
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(samples (S, K, 2), elites (E, K, 2), chosen (K, 2)) xy [m] of a PlanResult's last iteration: road-frame
    (s, d), or with ``road_frame`` (the :class:`~driveopt.sim.road_frame.RoadFrame` the plan was made in) world
    (X, Y) on any road, curved too. At most ``max_samples`` samples, evenly spread over the batch."""
    W = np.asarray(make_model(config.basis, config.qp).W)
    n = W.shape[1]
    coeffs = np.asarray(result.last.projected_coeffs)

    def xy(c: np.ndarray) -> np.ndarray:
        return np.stack([c[:, :n] @ W.T + result.x_offset, c[:, n:] @ W.T], axis=-1)

    pick = np.linspace(0, len(coeffs) - 1, min(max_samples, len(coeffs))).astype(int)
    chosen = result.safe_trajectory
    samples, elites = xy(coeffs[pick]), xy(coeffs[np.asarray(result.last.elite_index)])
    chosen_xy = np.stack([chosen.x, chosen.y], axis=-1)
    if road_frame is None:
        return samples, elites, chosen_xy
    # every point is turned into the world one by one: the batch's lines keep WORLD_NODES nodes (first and last kept)
    nodes = np.unique(np.linspace(0, W.shape[0] - 1, min(WORLD_NODES, W.shape[0])).round().astype(int))
    return (world_points(road_frame, samples[:, nodes]), world_points(road_frame, elites[:, nodes]),
            world_points(road_frame, chosen_xy))


def world_points(road_frame: Any, sd: np.ndarray) -> np.ndarray:
    """World xy (..., 2) [m] of road-frame points ``sd`` (..., 2) [m] (arc length, lateral offset) of ``road_frame``."""
    sd = np.asarray(sd, float)
    flat = sd.reshape(-1, 2)
    x, y = road_frame.to_world(flat[:, 0], flat[:, 1])[:2]
    return np.stack([x, y], axis=-1).reshape(sd.shape)


class VideoWriter:
    """Write frames to an H.264 MP4 as they come (nothing is kept in memory). Use as a context manager.

    Frames of odd width or height are padded to even (their last row / column repeated), as H.264
    needs; every frame must have the shape of the first. Refuses SDL's ``dummy`` video driver
    (black frames) with a VideoError. The video is whole or absent: ffmpeg writes a hidden temporary
    sibling, which is checked (:func:`mp4_problem`) and renamed to ``path`` only when it is a complete
    MP4; a failed write (ffmpeg stopped, a full disk, a truncated file) is a VideoError and leaves no file.
    """

    def __init__(self, path: str | Path, fps: float):
        import imageio.v2 as imageio

        check_video_driver()
        self.path = Path(path)
        if self.path.suffix.lower() not in VIDEO_SUFFIXES:
            raise VideoError(f"video {self.path}: expected a file ending in {', '.join(VIDEO_SUFFIXES)}")
        self._tmp = temporary_sibling(self.path)
        try:
            self._writer = imageio.get_writer(str(self._tmp), fps=fps, codec="libx264", macro_block_size=1, quality=7)
        except BaseException:
            self._tmp.unlink(missing_ok=True)
            raise
        self._shape: tuple[int, ...] | None = None
        self._open = True
        self.frames = 0

    def append(self, frame: np.ndarray) -> None:
        frame = np.asarray(frame)
        if self._shape is None:
            check_video_driver()  # the env has rendered by now: pygame knows its real driver
            self._shape = frame.shape
        elif frame.shape != self._shape:
            raise ValueError(f"frame shape changed from {self._shape} to {frame.shape}")
        with warnings.catch_warnings():
            # The first frame starts ffmpeg (fork, then exec at once); JAX's fork detector would warn of a
            # deadlock that cannot happen in a process that only execs.
            warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
            try:
                self._writer.append_data(pad_to_even(frame))
            except OSError as exc:  # ffmpeg ended: it could not write (a full disk) or was killed
                raise VideoError(f"cannot write {self.path}: ffmpeg stopped ({_first_line(exc)})") from None
        self.frames += 1

    def close(self) -> None:
        """Finish the MP4 and put it at ``path``; VideoError (and no file) when ffmpeg failed or the file is not a
        complete MP4."""
        if not self._open:
            return
        self._open = False
        try:
            self._writer.close()
        except (OSError, RuntimeError) as exc:
            self._tmp.unlink(missing_ok=True)
            raise VideoError(f"cannot write {self.path}: ffmpeg failed ({_first_line(exc)})") from None
        problem = mp4_problem(self._tmp)
        if problem:
            self._tmp.unlink(missing_ok=True)
            raise VideoError(f"cannot write {self.path}: the MP4 ffmpeg wrote is incomplete ({problem}); is the disk full?")
        commit(self._tmp, self.path)

    def abort(self) -> None:
        """Stop ffmpeg and remove what it wrote: the episode failed, so no video is kept."""
        if not self._open:
            return
        self._open = False
        with contextlib.suppress(Exception):
            self._writer.close()
        self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0]


def mp4_problem(path: str | Path) -> str | None:
    """What makes ``path`` not a complete MP4, in words ("truncated at 4096 bytes", "no movie header ..."); None
    when its top-level boxes tile the file and hold the media data and the movie header (``moov``, which ffmpeg
    writes last: a write cut short by a full disk has none)."""
    path = Path(path)
    size = path.stat().st_size
    kinds = set()
    with open(path, "rb") as f:
        offset = 0
        while offset < size:
            header = f.read(8)
            if len(header) < 8:
                return f"truncated at {size} bytes (a box header is cut short)"
            length, kind = struct.unpack(">I4s", header)
            if length == 1:  # a 64-bit size follows
                extended = f.read(8)
                if len(extended) < 8:
                    return f"truncated at {size} bytes (a box header is cut short)"
                length = struct.unpack(">Q", extended)[0]
            elif length == 0:  # the box runs to the end of the file
                length = size - offset
            if length < 8 or offset + length > size:
                return f"truncated at {size} bytes (its {kind.decode('latin-1')!r} box needs {offset + length})"
            kinds.add(kind)
            offset += length
            f.seek(offset)
    if b"mdat" not in kinds:
        return f"no media data in {size} bytes"
    if b"moov" not in kinds:
        return f"no movie header after {size} bytes"
    return None
