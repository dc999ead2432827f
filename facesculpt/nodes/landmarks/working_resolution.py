"""Landmarks at a working resolution: a large frame is halved (each output pixel the mean of a 2 x 2
block) until it holds at most ``max_pixels``, the faces are tracked on that copy, and their points
and crops are carried back to the frame's pixels. The networks see 128 and 192 pixel crops, so
a 4K frame gives them nothing a 1080p copy does not; the copy costs one cheap exact 2:1 reduction
where the crops of a 4K frame each needed a large area reduction (docs/architecture.md "Stages", 1).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from facesculpt.geometry.halving import halve, halvings, to_frame_pixels

from .detector import Face

#: Landmarks run on a copy of a larger frame halved to at most this many pixels (1920x1080).
ANALYSIS_PIXELS = 1920 * 1080


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
        points[:, :2] = to_frame_pixels(points[:, :2], times)
        points[:, 2] *= s
        roi = face.roi.astype(np.float32, copy=True)
        roi[:2] = to_frame_pixels(roi[:2], times)
        roi[2:4] *= s
        out.append(dataclasses.replace(face, points=points, roi=roi))
    return out


def track_at_working_resolution(detector, frame_bgr: np.ndarray, max_pixels: int) -> list[Face]:
    """``detector.track`` (a :class:`LandmarkDetector`) on ``frame_bgr`` (H, W, 3) uint8 halved to
    at most ``max_pixels`` (:func:`~facesculpt.geometry.halving.halvings`; <= 0: the frame as it
    is), the faces in the frame's pixels. Every frame of a video must go through here with the
    same ``max_pixels`` (the tracker keeps its crops in the copy's pixels)."""
    times = halvings(frame_bgr.shape[1], frame_bgr.shape[0], max_pixels)
    return to_full_resolution(detector.track(halve(frame_bgr, times)), times)
