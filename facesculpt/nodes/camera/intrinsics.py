"""Pinhole intrinsics."""

from __future__ import annotations

import math

import numpy as np


def intrinsics_from_fov(width: int, height: int, fov_deg: float = 60.0) -> np.ndarray:
    """K (3, 3) float64 for a pinhole camera with horizontal field of view ``fov_deg``,
    square pixels and the principal point at the image centre (pixels)."""
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    if not 1.0 <= fov_deg <= 179.0:
        raise ValueError(f"fov_deg must be within 1..179, got {fov_deg}")
    f = 0.5 * width / math.tan(math.radians(fov_deg) / 2.0)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])
