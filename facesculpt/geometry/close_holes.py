"""Closing the holes (eyes, mouth) of an open face mesh.

A face mesh such as the 468-point face mesh leaves the mouth (and sometimes the eyes) open. The
renderer draws the face region as the mesh's silhouette, so an open mouth would keep the *old*
mouth interior in place while the lips move; closing each hole with a fan of triangles makes the
region the filled outline and carries the hole's texture along with its rim. The deformer solves
on the closed mesh too, so a hole's rim does not bend more freely than the skin around it.
"""

from __future__ import annotations

import numpy as np

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
