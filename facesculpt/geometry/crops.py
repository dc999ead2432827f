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


def letterbox_roi(width: int, height: int) -> np.ndarray:
    """The square ROI (5,) that letterboxes a whole (width, height) frame (centred, black bars)."""
    side = float(max(width, height))
    return np.array([width / 2.0, height / 2.0, side, side, 0.0])


def network_input(image: np.ndarray, roi: np.ndarray, size: int, low: float = 0.0,
                  border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
    """A network's input (1, size, size, 3) float32 RGB with values in [low, 1]: the rotated ``roi``
    (continuous pixels) of an (H, W, 3) uint8 BGR image, resampled by :func:`crop_image`."""
    crop = crop_image(image, roi, size, border)
    return (crop[:, :, ::-1].astype(np.float32) * ((1.0 - low) / 255.0) + low)[None]


def crop_to_image(raw: np.ndarray, roi: np.ndarray, size: int) -> np.ndarray:
    """Points (N, 3) a network gave in the pixels of a ``size`` crop of ``roi`` -> (N, 3) in image
    pixels (continuous): x, y through the crop's rotation and scale, z scaled like x."""
    cx, cy, w, h, angle = (float(v) for v in roi)
    local = (raw[:, :2] / size - 0.5) * np.array([w, h])
    xy = local @ rotation_2d(angle).T + np.array([cx, cy])
    return np.hstack([xy, raw[:, 2:3] / size * w])


def rotated_box(points_xy: np.ndarray, angle: float) -> tuple[np.ndarray, float, float]:
    """The box of points (N, 2) (pixels) along axes turned by ``angle`` radians: its centre (2,)
    in image pixels, its width and height (pixels) along those axes."""
    rot = rotation_2d(angle)
    local = points_xy @ rot  # coordinates along the turned x and y axes
    lo, hi = local.min(0), local.max(0)
    w, h = (float(v) for v in (hi - lo))
    return rot @ ((lo + hi) / 2.0), w, h


def in_central_half(point: np.ndarray, roi: np.ndarray) -> bool:
    """True when ``point`` (2,) lies inside the central half (half the width and height) of the
    rotated ``roi`` (5,), both in the same pixels."""
    local = (np.asarray(point) - roi[:2]) @ rotation_2d(float(roi[4]))
    return bool(np.all(np.abs(local) < roi[2:4] / 4.0))


def pixel_indices(points: np.ndarray, roi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) and a ROI (5,) in continuous pixels (pixel i spans [i, i + 1]) -> float32
    copies in pixel indices (the centre of pixel i at i): x, y and the ROI's centre less 0.5."""
    points = points.astype(np.float32)
    points[:, :2] -= 0.5
    roi = roi.astype(np.float32)
    roi[:2] -= 0.5
    return points, roi
