"""The gaze drawn over a frame: each eye's ray as a line from the eye across the image, a ring on
each eye, and a bar across an eye that is closed (issue 48; the window's overlay and the docs' pictures).

A plain function of arrays (no window, no OpenGL): the eyeballs' centres and gaze directions in
camera space (mm, OpenCV axes) as ``face/gaze`` (:class:`facesculpt.msgs.FaceGaze`) or the
pipeline's ``fit.gaze`` carry them, and the camera's intrinsics.
"""

from __future__ import annotations

import cv2
import numpy as np

RAY_BGR = (60, 220, 60)          # green rays
CLOSED_BGR = (0, 140, 255)       # orange bar across a closed eye
#: How far a ray is drawn from the eye, mm, and where it starts (the eyeball's front), mm.
RAY_MM = 80.0
START_MM = 12.0


def _pixel(K: np.ndarray, X: np.ndarray) -> tuple[int, int] | None:
    if not np.all(np.isfinite(X)) or X[2] <= 1e-6:
        return None
    u = K[:2, :2] @ (X[:2] / X[2]) + K[:2, 2]
    return int(round(float(u[0]))), int(round(float(u[1])))


def draw_gaze(image: np.ndarray, K: np.ndarray, centres: np.ndarray, directions: np.ndarray, closed=(False, False),
              ray_mm: float = RAY_MM) -> np.ndarray:
    """A copy of ``image`` (H, W, 3) uint8 BGR with the gaze drawn: centres (2, 3) the eyeballs'
    centres and directions (2, 3) their unit gaze (NaN: none) in camera space mm, K (3, 3) the
    pinhole intrinsics (pixel indices), closed (2,) which eyes are closed. Each open eye gets a
    ring at its front and a line along its ray's part across the image, as long as ``ray_mm`` of
    it would be at the eye's depth (a gaze into the camera is a ring without a line, a gaze to
    the side a long line that way); a closed eye gets a short bar."""
    out = image.copy()
    K = np.asarray(K, np.float64)
    thickness = max(1, int(round(min(out.shape[:2]) / 300)))
    for c, d, shut in zip(np.asarray(centres, np.float64), np.asarray(directions, np.float64), closed):
        if shut or not np.all(np.isfinite(d)):
            p = _pixel(K, c)
            if p is not None:
                half = max(4, 3 * thickness)
                cv2.line(out, (p[0] - half, p[1]), (p[0] + half, p[1]), CLOSED_BGR, thickness + 1, cv2.LINE_AA)
            continue
        front = c + START_MM * d
        a = _pixel(K, front)
        if a is None:
            continue
        across = float(K[0, 0]) * ray_mm / front[2] * d[:2]  # the ray's part across the image, px
        b = (int(round(a[0] + across[0])), int(round(a[1] + across[1])))
        cv2.circle(out, a, 2 * thickness + 1, RAY_BGR, thickness, cv2.LINE_AA)
        cv2.line(out, a, b, RAY_BGR, thickness, cv2.LINE_AA)
    return out
