"""Turning pointer and joystick input into model-space displacements of a handle.

Pose convention (FaceState): ``x_cam = scale * R @ x_model + t``, camera space as in
facesculpt.geometry.projection. A camera-space displacement ``dc`` is ``R.T @ dc / scale`` in model space (mm).
"""

from __future__ import annotations

import numpy as np

from facesculpt.geometry.projection import pixel_ray


def camera_to_model_vector(delta_cam: np.ndarray, R: np.ndarray, scale: float) -> np.ndarray:
    """Model-space vector (3,) mm of a camera-space displacement (3,) under the inverse pose."""
    return np.asarray(R, dtype=np.float64).T @ np.asarray(delta_cam, dtype=np.float64) / float(scale)


def drag_delta(
    handle_cam: np.ndarray,
    start_px,
    end_px,
    K: np.ndarray,
    R: np.ndarray,
    scale: float,
    projection: str = "perspective",
) -> np.ndarray:
    """Model-space displacement (3,) mm of a handle at camera-space ``handle_cam`` (3,) when
    the pointer moves from pixel ``start_px`` (x, y) to ``end_px``: the motion of the pointer's
    ray at the handle's depth (the handle moves in the image plane through it)."""
    p = np.asarray(handle_cam, dtype=np.float64)

    def at_depth(px):
        origin, direction = pixel_ray(float(px[0]), float(px[1]), K, projection)
        if projection == "perspective":
            return direction * (p[2] / direction[2])
        return np.array([origin[0], origin[1], p[2]])

    return camera_to_model_vector(at_depth(end_px) - at_depth(start_px), R, scale)


def depth_delta(
    handle_cam: np.ndarray,
    depth_mm: float,
    R: np.ndarray,
    projection: str = "perspective",
) -> np.ndarray:
    """Model-space displacement (3,) of ``depth_mm`` model millimetres along the view ray
    through the handle; positive moves toward the camera (InputEvent.depth)."""
    p = np.asarray(handle_cam, dtype=np.float64)
    if projection == "perspective":
        away = p / max(np.linalg.norm(p), 1e-12)
    else:
        away = np.array([0.0, 0.0, 1.0])
    away_model = np.asarray(R, dtype=np.float64).T @ away  # a unit vector stays unit under R^T
    return -float(depth_mm) * away_model
