"""Mesh preparation for rendering: close the holes (eyes, mouth) of an open face mesh, and
the vertices within a few edges of each vertex.

A face mesh such as the 468-point face mesh leaves the mouth (and sometimes the
eyes) open. The renderer draws the face region as the mesh's silhouette, so an
open mouth would keep the *old* mouth interior in place while the lips move.
Closing each hole with a fan of triangles makes the region the filled outline
and carries the hole's texture along with its rim.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from facesculpt.geometry.boundary_loops import boundary_loops


def close_holes(triangles: np.ndarray) -> np.ndarray:
    """Triangles plus fan triangles closing every boundary loop but the longest (the outline).

    triangles: (T, 3) int. Returns (T + added, 3) int32; the input when there is no hole.
    The fan starts at each hole's first vertex and keeps the mesh's winding.
    """
    tri = np.asarray(triangles, np.int32)
    loops = boundary_loops(tri)
    extra = []
    for loop in loops[1:]:
        # The boundary runs against the winding of its adjacent triangles, so a fan over
        # the reversed loop has the same orientation as the mesh.
        rev = loop[::-1]
        for i in range(1, len(rev) - 1):
            extra.append((rev[0], rev[i], rev[i + 1]))
    if not extra:
        return tri
    return np.concatenate([tri, np.asarray(extra, np.int32)])


def vertex_rings(triangles: np.ndarray, n_vertices: int, rings: int) -> sp.csr_matrix:
    """(V, V) float32 sparse R with R[i, j] > 0 where vertex j lies within ``rings`` edges of
    vertex i (itself included, if some triangle has it) over ``triangles`` (T, 3) int:
    ``R @ marked > 0`` marks the vertices near any of the ``marked`` (V,) ones."""
    tri = np.asarray(triangles, np.int64)
    used = np.unique(tri)   # a vertex of no triangle is near nothing, not even itself
    rows = np.concatenate([tri[:, a] for a in (0, 0, 1, 1, 2, 2)] + [used])
    cols = np.concatenate([tri[:, b] for b in (1, 2, 0, 2, 0, 1)] + [used])
    step = sp.csr_matrix((np.ones(len(rows), np.float32), (rows, cols)), shape=(n_vertices, n_vertices))
    step.data[:] = 1.0
    near = step
    for _ in range(rings - 1):
        near = near @ step
        near.data[:] = 1.0   # only whether, not how many paths: keeps the values small
    return near.tocsr()
