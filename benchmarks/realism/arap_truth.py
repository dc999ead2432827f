"""The ground-truth edit as an as-rigid-as-possible deformation, the benchmark's own solver (it does
not use the project's deformer): what a deformer preset means (handles moved, the surface within
the ROI following as rigidly as it can, everything else still), as the alternative to the
raised-cosine falloff of :mod:`.edits` (``bench_realism.py --truth-edit arap``).

Sorkine & Alexa's ARAP: cotangent weights (negative ones clamped to zero), one cell per vertex
(its spokes), local rotations by SVD and a global sparse solve, alternated until the vertices
stop moving. The ROI: the vertices within ``radius`` mm of a handle along the mesh's edges
(Dijkstra on the edge lengths); every vertex outside it is fixed. A handle grips the skin within
``grip`` times the radius of it (the same distance), which moves rigidly with it, as a deformer
handle does with ``deformer.grip`` 0.2 (an option; by default a handle is a single vertex, as in
the paper's ARAP: :mod:`.paper_arap`); each gripped vertex follows its nearest handle.

Arrays: rest (V, 3) float mm, triangles (T, 3) int, displacements (V, 3) float mm.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra
from scipy.sparse.linalg import factorized

TOLERANCE_MM = 1e-5    # the solve stops when no vertex moves this far in an iteration
MAX_ITERATIONS = 2000


def cotangent_matrix(rest: np.ndarray, triangles: np.ndarray) -> sp.csr_matrix:
    """(V, V) symmetric: each edge's weight, half the sum of the cotangents of the angles opposite
    it (clamped at zero)."""
    n = len(rest)
    rows, cols, vals = [], [], []
    for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):   # the edge (a, b) opposite the corner c
        i, j, k = triangles[:, a], triangles[:, b], triangles[:, c]
        u, v = rest[i] - rest[k], rest[j] - rest[k]
        cot = np.einsum("ij,ij->i", u, v) / np.maximum(np.linalg.norm(np.cross(u, v), axis=1), 1e-12)
        rows += [i, j]
        cols += [j, i]
        vals += [0.5 * cot, 0.5 * cot]
    W = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
    W.data = np.maximum(W.data, 0.0)
    return W


def edge_distances(rest: np.ndarray, triangles: np.ndarray, handles: list[int], radius: float) -> np.ndarray:
    """(H, V): each vertex's distance (mm) from each of ``handles`` along the mesh's edges (inf
    beyond ``radius``)."""
    # each edge once: a pair given twice would be summed into one edge of twice the length
    e = np.unique(np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1),
                  axis=0)
    length = np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1)
    graph = sp.coo_matrix((length, (e[:, 0], e[:, 1])), shape=(len(rest),) * 2).tocsr()
    return np.atleast_2d(dijkstra(graph, directed=False, indices=handles, limit=radius * 1.0001))


def arap_displacement(rest: np.ndarray, triangles: np.ndarray, handles: dict[int, np.ndarray],
                      radius: float, grip: float = 0.2) -> np.ndarray:
    """The displacement of ``rest`` when each handle vertex of ``handles`` (vertex -> offset (3,)
    mm) and its grip are moved by its offset and the ROI of ``radius`` mm deforms as rigidly as
    possible."""
    rest = np.asarray(rest, np.float64)
    n = len(rest)
    idx = np.array(list(handles), np.int64)
    d = edge_distances(rest, np.asarray(triangles, np.int64), list(idx), radius)
    nearest = np.argmin(d, axis=0)
    to_handle = d.min(axis=0)
    gripped = to_handle <= grip * radius
    gripped[idx] = True
    free = (to_handle <= radius) & ~gripped
    target = rest.copy()
    offsets = np.array([handles[h] for h in idx], np.float64)
    target[gripped] += offsets[nearest[gripped]]
    W = cotangent_matrix(rest, np.asarray(triangles, np.int64))
    L = (sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W).tocsr()
    f = np.flatnonzero(free)
    c = np.flatnonzero(~free)
    solve = factorized(L[f][:, f].tocsc())
    L_fc = L[f][:, c]
    Wc = W.tocoo()
    i, j, w = Wc.row, Wc.col, Wc.data
    e0 = rest[i] - rest[j]
    X = target.copy()
    for _ in range(MAX_ITERATIONS):
        e1 = X[i] - X[j]
        S = np.zeros((n, 3, 3))
        np.add.at(S, i, w[:, None, None] * e0[:, :, None] * e1[:, None, :])
        U, _, Vt = np.linalg.svd(S)
        R = np.einsum("nji,nkj->nik", Vt, U)   # V U^T
        flip = np.linalg.det(R) < 0
        if flip.any():
            U[flip, :, 2] *= -1
            R[flip] = np.einsum("nji,nkj->nik", Vt[flip], U[flip])
        b = np.zeros((n, 3))
        np.add.at(b, i, 0.5 * w[:, None] * np.einsum("nij,nj->ni", R[i] + R[j], e0))
        rhs = b[f] - L_fc @ X[c]
        new = np.column_stack([solve(rhs[:, k]) for k in range(3)])
        moved = np.abs(new - X[f]).max() if len(f) else 0.0
        X[f] = new
        if moved < TOLERANCE_MM:
            break
    return X - rest
