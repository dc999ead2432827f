"""The first triangle of a mesh that a ray hits (picking in the deformer, the surface point under
a corrected landmark in the fitter)."""

from __future__ import annotations

import numpy as np


def ray_mesh_hit(
    origin: np.ndarray,
    direction: np.ndarray,
    vertices: np.ndarray,
    triangles: np.ndarray,
    two_sided_line: bool = False,
) -> tuple[int, float, np.ndarray] | None:
    """First triangle hit by a ray (Moller-Trumbore over all triangles, vectorised).

    origin, direction (3,); vertices (V, 3); triangles (T, 3). Both faces of a triangle count.
    ``two_sided_line`` also accepts hits behind the origin (an orthographic ray is a line: the
    nearest hit along +direction from the most negative one is the visible one).
    Returns (triangle, distance t, barycentric (3,)) or None on a miss.
    """
    Vx = np.asarray(vertices, dtype=np.float64)
    T = np.asarray(triangles, dtype=np.int64)
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    p0, p1, p2 = Vx[T[:, 0]], Vx[T[:, 1]], Vx[T[:, 2]]
    e1, e2 = p1 - p0, p2 - p0
    pvec = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, pvec)
    ok = np.abs(det) > 1e-12 * (np.einsum("ij,ij->i", e1, e1) + np.einsum("ij,ij->i", e2, e2))
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tvec = o - p0
    u = np.einsum("ij,ij->i", tvec, pvec) * inv
    qvec = np.cross(tvec, e1)
    v = (qvec @ d) * inv
    t = np.einsum("ij,ij->i", e2, qvec) * inv
    eps = 1e-9
    hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1.0 + eps)
    if not two_sided_line:
        hit &= t > 0
    if not np.any(hit):
        return None
    idx = np.flatnonzero(hit)
    k = idx[np.argmin(t[idx])]
    return int(k), float(t[k]), np.array([1.0 - u[k] - v[k], u[k], v[k]])
