"""Normals of a triangle mesh: per triangle and, area-weighted, per vertex (the renderer's atlas
rasteriser and the fitter's appearance refinement)."""

from __future__ import annotations

import numpy as np


def face_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(T, 3) float64 normals of the (T, 3) int ``triangles`` of (V, 3) ``vertices``, as long as
    twice each triangle's area (right-handed corner order)."""
    X = np.asarray(vertices, np.float64)
    tri = np.asarray(triangles, np.int64)
    return np.cross(X[tri[:, 1]] - X[tri[:, 0]], X[tri[:, 2]] - X[tri[:, 0]])


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray, faces: np.ndarray | None = None) -> np.ndarray:
    """(V, 3) float64 unit normals of the vertices, each the area-weighted sum of its triangles'
    (``faces``: their :func:`face_normals` when already computed); zero for a vertex in no triangle."""
    tri = np.asarray(triangles, np.int64)
    fn = face_normals(vertices, tri) if faces is None else faces
    corners = tri.T.ravel()
    n = np.column_stack([np.bincount(corners, np.tile(fn[:, j], 3), minlength=len(vertices)) for j in range(3)])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
