"""Camera projection under the graph's conventions (FaceState and the fitter).

Camera space is OpenCV's (x right, y down, z away from the camera).

* ``perspective``: a camera-space point (X, Y, Z) is at pixel ``K @ (X, Y, Z) / Z`` (intrinsics
  K (3, 3), pixels); a pixel's ray starts at the camera centre.
* ``orthographic`` (scaled orthographic): camera space is in pixel scale and a point's pixel is
  its (x, y); K is not used; every ray is parallel to +z. A model point x maps to camera space
  as ``s R x + t``.
* a general (3, 4) matrix P (the renderer's, estimated from the fitter's own pairs): pixel =
  ``P @ [X, 1]`` divided by its third coordinate.
"""

from __future__ import annotations

import numpy as np

PROJECTIONS = ("perspective", "orthographic")


def _unknown(projection: str) -> ValueError:
    return ValueError(f"unknown projection {projection!r} (use one of {PROJECTIONS})")


def project(points: np.ndarray, K: np.ndarray | None, projection: str = "perspective") -> np.ndarray:
    """Pixels (N, 2) float64 of camera-space points (N, 3); ``K`` (3, 3) under perspective only."""
    P = np.asarray(points, dtype=np.float64)
    if projection == "perspective":
        h = P @ np.asarray(K, dtype=np.float64).T
        return h[:, :2] / h[:, 2:3]
    if projection == "orthographic":
        return P[:, :2].copy()
    raise _unknown(projection)


def project_orthographic(points: np.ndarray, R: np.ndarray, t: np.ndarray, s: float) -> np.ndarray:
    """(N, 3) model points -> (N, 2) pixels under the scaled orthographic camera (R (3, 3),
    t (3,) or (2,) pixels, s pixels per model unit)."""
    t = np.asarray(t, np.float64).ravel()
    return s * (np.asarray(points, np.float64) @ np.asarray(R, np.float64).T)[:, :2] + t[:2]


def project_with_matrix(P: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) and the homogeneous coordinate w (N,) of points (N, 3) under P (3, 4).

    Raises ValueError when a point lies on the camera plane (w = 0).
    """
    X = np.asarray(points, np.float64)
    h = X @ P[:, :3].T + P[:, 3]
    w = h[:, 2]
    if np.any(w == 0):
        raise ValueError("a vertex lies on the camera plane (cannot be projected)")
    return h[:, :2] / w[:, None], w


def pixel_ray(x: float, y: float, K: np.ndarray | None, projection: str = "perspective") -> tuple[np.ndarray, np.ndarray]:
    """Ray (origin (3,), unit direction (3,)) in camera space through pixel (x, y); ``K`` (3, 3)
    is used under ``perspective`` only."""
    if projection == "perspective":
        d = np.linalg.solve(np.asarray(K, dtype=np.float64), np.array([x, y, 1.0]))
        return np.zeros(3), d / np.linalg.norm(d)
    if projection == "orthographic":
        return np.array([x, y, 0.0], dtype=np.float64), np.array([0.0, 0.0, 1.0])
    raise _unknown(projection)
