"""The vertices within a few edges of each vertex of a render mesh: the compositor works on the
triangles near a moved vertex, as far as subdivision spreads its offset."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


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
