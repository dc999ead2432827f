"""The bounding box and the centroid of a point set, computed fast.

``points.min(axis=0)`` or ``points.mean(axis=0)`` on an (N, 2) or (N, 3) array reduces across its
short rows, which numpy does an order of magnitude slower than one reduction per column (or one
matrix-vector product); the renderer and the fitter take these of a face's thousands of
vertices several times a frame.
"""

from __future__ import annotations

import numpy as np


def point_bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo (d,), hi (d,)): the smallest and largest value of each coordinate of ``points`` (N, d),
    N >= 1, in their dtype."""
    p = np.asarray(points)
    lo = np.array([p[:, j].min() for j in range(p.shape[1])], p.dtype)
    hi = np.array([p[:, j].max() for j in range(p.shape[1])], p.dtype)
    return lo, hi


def centroid(points: np.ndarray) -> np.ndarray:
    """(d,) float64: the mean of ``points`` (N, d), N >= 1."""
    p = np.asarray(points, np.float64)
    return p.T @ np.full(len(p), 1.0 / len(p))
