"""Rotated square crops of an image: the ROI (centre, size, angle) a detector or a landmark network
looks at, as an affine map and as the resampled crop (the landmarks and hands rooms share them).

ROIs are (5,) [cx, cy, w, h, angle_rad] in continuous pixel coordinates (the image's pixel i
spans [i, i + 1)); the angle turns the crop's x axis from the image's.
"""

from __future__ import annotations

import math

import cv2
import numpy as np


def rotation_2d(angle: float) -> np.ndarray:
    """(2, 2) rotation by ``angle`` radians (counter-clockwise in x-right, y-up; in image
    coordinates, y down, it turns x toward y)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


def crop_matrix(roi: np.ndarray, size: int) -> np.ndarray:
    """2x3 affine map from crop pixel indices to image pixel indices (for WARP_INVERSE_MAP)."""
    cx, cy, w, h, angle = (float(v) for v in roi)
    rot = rotation_2d(angle)
    lin = rot @ np.diag([w / size, h / size])
    # image_cont = c + rot @ ((q + 0.5) / size - 0.5) * (w, h); image index = image_cont - 0.5.
    offset = np.array([cx, cy]) + rot @ ((0.5 / size - 0.5) * np.array([w, h])) - 0.5
    return np.hstack([lin, offset[:, None]])


def _multiple_span(lo: int, hi: int, limit: int, factor: int) -> tuple[int, int]:
    """[lo, hi) grown (up to [0, limit)) or, where the image ends, trimmed to a multiple of ``factor``."""
    n = -(-(hi - lo) // factor) * factor
    hi = min(lo + n, limit)
    lo = max(hi - n, 0)
    return lo, lo + (hi - lo) // factor * factor if hi - lo >= factor else hi


def crop_image(image: np.ndarray, roi: np.ndarray, size: int, border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
    """The rotated ROI (continuous pixels) of an (H, W, C) uint8 image resampled to (size, size, C)
    (channel order kept). Outside the image:
    ``border`` (replicate the edge pixels for the mesh, black for the detector's letterbox)."""
    matrix = crop_matrix(roi, size)
    # Work on the part of the image under the ROI (plus a margin for interpolation).
    corners = matrix @ np.array([[0, 0, 1], [size, 0, 1], [0, size, 1], [size, size, 1]], np.float64).T
    h, w = image.shape[:2]
    x0, y0 = (int(np.clip(math.floor(v) - 2, 0, lim)) for v, lim in zip(corners.min(axis=1), (w - 1, h - 1)))
    x1, y1 = (int(np.clip(math.ceil(v) + 3, 1, lim)) for v, lim in zip(corners.max(axis=1), (w, h)))
    if x1 <= x0 or y1 <= y0:  # the ROI misses the image entirely
        x0, y0, x1, y1 = 0, 0, w, h
    shrink = float(max(roi[2], roi[3])) / size
    if shrink >= 2.0:
        # Sides a whole multiple of the factor (grown into the image, else trimmed): OpenCV's
        # area resize by an exact integer factor is many times faster than its general path.
        f = int(shrink)
        x0, x1 = _multiple_span(x0, x1, w, f)
        y0, y1 = _multiple_span(y0, y1, h, f)
    part = image[y0:y1, x0:x1]
    matrix = matrix - np.array([[0.0, 0.0, x0], [0.0, 0.0, y0]])
    if shrink >= 2.0:
        # Area-downsample by a whole factor first so the bilinear warp shrinks by less than 2 and
        # does not alias (a whole frame into the detector, a face filling a 4K frame).
        factor = float(int(shrink))
        small_size = (max(int(round(part.shape[1] / factor)), 1), max(int(round(part.shape[0] / factor)), 1))
        small = cv2.resize(part, small_size, interpolation=cv2.INTER_AREA)
        sx, sy = part.shape[1] / small.shape[1], part.shape[0] / small.shape[0]
        matrix = matrix.copy()
        matrix[0] = (matrix[0] + np.array([0.0, 0.0, 0.5])) / sx - np.array([0.0, 0.0, 0.5])
        matrix[1] = (matrix[1] + np.array([0.0, 0.0, 0.5])) / sy - np.array([0.0, 0.0, 0.5])
        part = small
    return cv2.warpAffine(part, matrix, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=border, borderValue=(0, 0, 0))
