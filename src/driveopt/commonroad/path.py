"""A curvilinear frame along a polyline (numpy only): stations and offsets of points, and back to the plane.

``s`` [m] is the station along the path (0 at its first given point), ``d`` [m] the signed offset, positive to the
left of travel: driveopt's road frame (:mod:`driveopt.scene`). The path is resampled every :data:`STEP` metres and
extended straight by :data:`EXTENSION` metres at both ends, so that points a little before its start or beyond its
end (a car behind the ego, a prediction past the map) still have coordinates.
"""

from __future__ import annotations

import numpy as np

STEP = 0.5  # [m] resampling distance
EXTENSION = 200.0  # [m] straight extension at both ends


class PathFrame:
    """Frenet coordinates along a polyline of (M, 2) points [m]."""

    def __init__(self, points: np.ndarray) -> None:
        points = np.asarray(points, dtype=np.float64)
        keep = np.concatenate([[True], np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-6])
        points = points[keep]
        if len(points) < 2:
            raise ValueError("a path needs two distinct points")
        lengths = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
        stations = np.arange(0.0, lengths[-1], STEP).tolist() + [lengths[-1]]
        core = np.stack([np.interp(stations, lengths, points[:, i]) for i in range(2)], axis=1)
        start_dir = _unit(core[1] - core[0])
        end_dir = _unit(core[-1] - core[-2])
        ext = np.arange(STEP, EXTENSION + STEP, STEP)
        before = core[0] - ext[::-1, None] * start_dir
        after = core[-1] + ext[:, None] * end_dir
        self.points = np.concatenate([before, core, after])  # (M, 2)
        seg = np.diff(self.points, axis=0)
        self.seg_length = np.linalg.norm(seg, axis=1)
        self.seg_dir = seg / self.seg_length[:, None]
        self.s = np.concatenate([[0.0], np.cumsum(self.seg_length)])  # [m] station of each point
        self.s -= self.s[len(before)]  # the first given point at s = 0
        self.length = float(lengths[-1])  # [m] of the given path
        heading = np.unwrap(np.arctan2(self.seg_dir[:, 1], self.seg_dir[:, 0]))
        mid = 0.5 * (self.s[:-1] + self.s[1:])
        self._heading_s, self._heading = mid, heading
        curvature = np.gradient(heading, mid) if len(mid) > 1 else np.zeros(1)
        self._curvature = np.convolve(curvature, np.ones(9) / 9.0, mode="same")  # smoothed over 4.5 m

    def heading(self, s: np.ndarray) -> np.ndarray:
        """[rad] direction of the path at stations ``s``."""
        return np.interp(s, self._heading_s, self._heading)

    def curvature(self, s: np.ndarray) -> np.ndarray:
        """[1/m] signed curvature (positive turning left) at stations ``s``."""
        return np.interp(s, self._heading_s, self._curvature)

    def project(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(s, d) [m] of points (..., 2): the nearest point of the path."""
        xy = np.asarray(xy, dtype=np.float64)
        flat = xy.reshape(-1, 2)
        rel = flat[:, None, :] - self.points[None, :-1, :]  # (P, M-1, 2)
        along = np.clip(np.einsum("pmk,mk->pm", rel, self.seg_dir), 0.0, self.seg_length[None])
        foot = self.points[None, :-1, :] + along[..., None] * self.seg_dir[None]
        dist = np.linalg.norm(flat[:, None, :] - foot, axis=2)
        best = np.argmin(dist, axis=1)
        rows = np.arange(len(flat))
        s = self.s[best] + along[rows, best]
        dvec = flat - foot[rows, best]
        direction = self.seg_dir[best]
        d = np.sign(direction[:, 0] * dvec[:, 1] - direction[:, 1] * dvec[:, 0]) * dist[rows, best]
        return s.reshape(xy.shape[:-1]), d.reshape(xy.shape[:-1])

    def to_world(self, s: np.ndarray, d: np.ndarray) -> np.ndarray:
        """(..., 2) [m] points at stations ``s`` and offsets ``d``."""
        s, d = np.asarray(s, dtype=np.float64), np.asarray(d, dtype=np.float64)
        x = np.interp(s, self.s, self.points[:, 0])
        y = np.interp(s, self.s, self.points[:, 1])
        h = self.heading(s)
        return np.stack([x - np.sin(h) * d, y + np.cos(h) * d], axis=-1)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / max(float(np.linalg.norm(v)), 1e-9)
