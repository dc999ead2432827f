"""Exact 2:1 reductions of a frame and the pixel map between a halved copy and the frame: the
working resolution of the analysis path (landmarks on a copy of a large frame; the camera's
``camera/analysis`` topic). The landmarks and camera rooms share them.

Pixel indices have the centre of pixel i at i (OpenCV); a copy halved ``times`` times (s = 2 **
times) has pixel (i, j) covering pixels s*i .. s*i + s - 1 (and the same rows) of the frame, so
x_frame = (x_copy + 0.5) * s - 0.5.
"""

from __future__ import annotations

import cv2
import numpy as np


def halvings(width: int, height: int, max_pixels: int) -> int:
    """How many times a ``width`` x ``height`` frame is halved to hold at most ``max_pixels``
    pixels (0 when it already does, or when ``max_pixels`` <= 0: full resolution)."""
    n = 0
    while max_pixels > 0 and (width >> n) * (height >> n) > max_pixels and min(width >> n, height >> n) >= 64:
        n += 1
    return n


def halve(image: np.ndarray, times: int) -> np.ndarray:
    """(H, W, C) uint8 -> (H >> times, W >> times, C): each step averages 2 x 2 blocks (an odd last
    row or column is dropped first, so the scale is exactly 2 and pixel (i, j) of the copy covers
    pixels 2i..2i+1, 2j..2j+1 of the original). ``times`` 0 returns ``image`` itself."""
    for _ in range(times):
        h, w = image.shape[:2]
        image = cv2.resize(image[: h - h % 2, : w - w % 2], (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    return image


def to_frame_pixels(xy: np.ndarray, times: int) -> np.ndarray:
    """(..., 2) pixel positions in a copy halved ``times`` times -> the same in the frame's pixels
    (float32, a new array)."""
    s = float(1 << times)
    return ((np.asarray(xy, np.float32) + 0.5) * s - 0.5).astype(np.float32)


def halved_intrinsics(K: np.ndarray, times: int) -> np.ndarray:
    """(3, 3) pinhole intrinsics of a frame, pixels -> those of its copy halved ``times`` times."""
    return _rescaled_intrinsics(K, 1.0 / (1 << times))


def frame_intrinsics(K: np.ndarray, times: int) -> np.ndarray:
    """The inverse of :func:`halved_intrinsics`: a halved copy's (3, 3) K -> the frame's."""
    return _rescaled_intrinsics(K, float(1 << times))


def _rescaled_intrinsics(K: np.ndarray, s: float) -> np.ndarray:
    """K for pixels ``s`` times as many a side, the same pixel-centre map as :func:`to_frame_pixels`."""
    out = np.array(K, np.float64, copy=True)
    out[:2, :2] *= s
    out[:2, 2] = (out[:2, 2] + 0.5) * s - 0.5
    return out
