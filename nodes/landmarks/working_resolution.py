"""Landmarks at a working resolution: a large frame is halved (each output pixel the mean of a 2 x 2
block) until it holds at most ``max_pixels``, the faces are tracked on that copy, and their points
and crops are carried back to the frame's pixels. The networks see 128 and 192 pixel crops, so
a 4K frame gives them nothing a 1080p copy does not; the copy costs one cheap exact 2:1 reduction
where the crops of a 4K frame each needed a large area reduction (docs/architecture.md "Stages", 1).
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from .detector import Face


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
    pixels 2i..2i+1, 2j..2j+1 of the original)."""
    for _ in range(times):
        h, w = image.shape[:2]
        image = cv2.resize(image[: h - h % 2, : w - w % 2], (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    return image


def to_full_resolution(faces: list[Face], times: int) -> list[Face]:
    """Faces found on a copy halved ``times`` times, in the original frame's pixels: x, y (pixel
    indices, centre of pixel i at i) as (x + 0.5) * s - 0.5 with s = 2 ** times, depth z and the
    crop's sides times s, the crop's centre like x, y."""
    if times == 0:
        return faces
    s = float(1 << times)
    out = []
    for face in faces:
        points = face.points.astype(np.float32, copy=True)
        points[:, :2] = (points[:, :2] + 0.5) * s - 0.5
        points[:, 2] *= s
        roi = face.roi.astype(np.float32, copy=True)
        roi[:2] = (roi[:2] + 0.5) * s - 0.5
        roi[2:4] *= s
        out.append(dataclasses.replace(face, points=points, roi=roi))
    return out


def track_at_working_resolution(detector, frame_bgr: np.ndarray, max_pixels: int) -> list[Face]:
    """``detector.track`` (a :class:`LandmarkDetector`) on ``frame_bgr`` (H, W, 3) uint8 halved to
    at most ``max_pixels`` (:func:`halvings`; <= 0: the frame as it is), the faces in the frame's
    pixels. Every frame of a video must go through here with the same ``max_pixels`` (the
    tracker keeps its crops in the copy's pixels)."""
    times = halvings(frame_bgr.shape[1], frame_bgr.shape[0], max_pixels)
    return to_full_resolution(detector.track(halve(frame_bgr, times)), times)
