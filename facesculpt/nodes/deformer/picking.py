"""Picking: a pixel becomes a ray through the camera, the ray hits the current (deformed)
fitted mesh, and the nearest vertex of the hit triangle becomes the handle.

Camera conventions: :mod:`facesculpt.geometry.projection`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesculpt.geometry.projection import pixel_ray
from facesculpt.geometry.ray_mesh import ray_mesh_hit


@dataclass
class Pick:
    """A hit: ``vertex`` (the handle), ``triangle`` index, ``point`` (3,) camera space,
    ``distance`` along the unit ray (camera units), ``barycentric`` (3,) of the point."""

    vertex: int
    triangle: int
    point: np.ndarray
    distance: float
    barycentric: np.ndarray


def pick_vertex(
    x: float,
    y: float,
    K: np.ndarray,
    vertices_cam: np.ndarray,
    triangles: np.ndarray,
    projection: str = "perspective",
) -> Pick | None:
    """The handle under pixel (x, y): cast the pixel's ray at the camera-space mesh
    ``vertices_cam`` (V, 3) (the current deformed fitted mesh), take the first triangle hit
    and, of its three corners, the vertex nearest the hit point. None on a miss."""
    if not (np.isfinite(x) and np.isfinite(y)):
        return None
    origin, direction = pixel_ray(x, y, K, projection)
    hit = ray_mesh_hit(origin, direction, vertices_cam, triangles, two_sided_line=projection == "orthographic")
    if hit is None:
        return None
    tri, t, bary = hit
    point = origin + t * direction
    corners = np.asarray(triangles)[tri]
    dist = np.linalg.norm(np.asarray(vertices_cam, dtype=np.float64)[corners] - point, axis=1)
    return Pick(int(corners[np.argmin(dist)]), tri, point, t, bary)
