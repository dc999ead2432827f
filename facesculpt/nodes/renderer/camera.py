"""Projecting the deformed mesh with the camera the fitter used, without knowing that camera.

The fitter hands over its fitted mesh twice: in camera space (V, 3) and projected
to pixels (V, 2). Those pairs determine the 3x4 projection matrix (perspective or
orthographic alike) by the direct linear transform, so the renderer needs no
convention about K, axis directions or the projection kind: it fits P once per
frame and projects the deformed vertices with it. The deformed mesh's pixels
are taken as ``projected + (P(deformed) - P(fitted))`` so that a zero
deformation lands exactly on the fitter's own projection.
"""

from __future__ import annotations

import numpy as np

from facesculpt.geometry.point_bounds import centroid
from facesculpt.geometry.projection import project_with_matrix

# DLT on a spread-out subset: plenty for 11 unknowns, and cheap per frame.
MAX_DLT_POINTS = 300


def _normaliser(points: np.ndarray) -> np.ndarray:
    """Hartley normalisation: (d+1, d+1) similarity taking points to centroid 0, mean norm sqrt(d)."""
    d = points.shape[1]
    centre = points.mean(axis=0)
    spread = np.sqrt(((points - centre) ** 2).sum(axis=1)).mean()
    s = np.sqrt(d) / max(spread, 1e-12)
    T = np.eye(d + 1)
    T[:d, :d] *= s
    T[:d, d] = -s * centre
    return T


def estimate_projection(vertices: np.ndarray, projected: np.ndarray) -> np.ndarray:
    """The (3, 4) float64 matrix P with ``projected ~ P @ [vertices, 1]`` (least squares, DLT).

    vertices: (V, 3) camera space (any units); projected: (V, 2) pixels; V >= 6, not coplanar.
    Exact for perspective and for affine (orthographic, weak-perspective) cameras.
    Raises ValueError when the points do not determine a camera.
    """
    X = np.asarray(vertices, np.float64)
    x = np.asarray(projected, np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or x.shape != (X.shape[0], 2):
        raise ValueError(f"need (V, 3) vertices and (V, 2) projections, got {X.shape} and {x.shape}")
    if X.shape[0] < 6:
        raise ValueError(f"need at least 6 vertices to determine the projection, got {X.shape[0]}")
    if X.shape[0] > MAX_DLT_POINTS:
        X = X[:: X.shape[0] // MAX_DLT_POINTS + 1]
        x = x[:: x.shape[0] // MAX_DLT_POINTS + 1]
    T3, T2 = _normaliser(X), _normaliser(x)
    Xn = np.column_stack([X, np.ones(len(X))]) @ T3.T
    xn = np.column_stack([x, np.ones(len(x))]) @ T2.T
    n = len(X)
    A = np.zeros((2 * n, 12))
    A[0::2, 0:4] = Xn
    A[0::2, 8:12] = -xn[:, 0:1] * Xn
    A[1::2, 4:8] = Xn
    A[1::2, 8:12] = -xn[:, 1:2] * Xn
    _, sv, vt = np.linalg.svd(A, full_matrices=False)
    if sv[-2] < 1e-9 * sv[0]:
        raise ValueError("the fitted vertices do not determine a camera (degenerate, e.g. coplanar)")
    Pn = vt[-1].reshape(3, 4)
    P = np.linalg.solve(T2, Pn @ T3)
    return P / np.abs(P).max()


def project(P: np.ndarray, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels and view depth of camera-space ``vertices`` (V, 3) under ``P`` (3, 4).

    Returns (px (V, 2) float64, depth (V,) float64). depth grows away from the camera
    along the viewing ray through the points' centroid: with M = P[:, :3] and the
    centroid's pixel (u, v), that ray is cross(M0 - u M2, M1 - v M2) (the rows of the
    camera's local affine approximation), which covers perspective and affine cameras
    alike and does not depend on P's overall sign. Only depth *order* is meaningful;
    it assumes a right-handed camera frame seen without mirroring (image x right,
    y down), which holds for OpenCV- and OpenGL-style frames alike.
    """
    X = np.asarray(vertices, np.float64)
    px, _ = project_with_matrix(P, X)
    M = P[:, :3]
    centre = centroid(X)
    hc = M @ centre + P[:, 3]
    u, v = hc[0] / hc[2], hc[1] / hc[2]
    direction = np.cross(M[0] - u * M[2], M[1] - v * M[2])
    depth = X @ (direction / np.linalg.norm(direction))
    return px, depth
