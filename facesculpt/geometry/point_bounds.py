"""The bounding box of a point set, per coordinate.

``points.min(axis=0)`` on an (N, 2) array reduces across its short rows, which numpy does an
order of magnitude slower than one contiguous-stride reduction per column; the renderer takes
the box of every face's thousands of pixels several times a frame.
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
