"""The ARAP energy (the paper's Eq. 4) and its cotangent edge weights (libigl's ``cotmatrix``).

    E(P') = sum_i sum_{j in N(i)} w_ij || (p'_i - p'_j) - R_i (p_i - p_j) ||^2

with ``w_ij = (cot a_ij + cot b_ij) / 2`` and, per vertex cell, the rotation ``R_i`` that
minimises the cell's term (:func:`.rotations.fit_rotations`). Pure functions: arrays in, arrays out.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .rotations import fit_rotations


def cotangent_weights(vertices: np.ndarray, triangles: np.ndarray, clamp: bool = True) -> sp.csr_matrix:
    """Symmetric edge weights ``w_ij = (cot a_ij + cot b_ij) / 2`` of a triangle mesh.

    vertices: (V, 3) float, rest positions. triangles: (T, 3) int.
    clamp: obtuse angles have negative cotangents, which can make the energy non-convex in the
    global step; with ``clamp`` each angle's cotangent is clamped at 0 (and each edge weight
    floored at 1e-8 x the mean weight, so no edge drops out of the mesh graph). Without it
    the weights are exactly those of ``igl.cotmatrix`` (its off-diagonal entries).
    Returns (V, V) csr float64 with zero diagonal.
    """
    V = np.asarray(vertices, dtype=np.float64)
    T = np.asarray(triangles, dtype=np.int64)
    n = V.shape[0]
    rows, cols, vals = [], [], []
    for k in range(3):
        # angle at corner k is opposite edge (k+1, k+2)
        i, j, o = T[:, (k + 1) % 3], T[:, (k + 2) % 3], T[:, k]
        a = V[i] - V[o]
        b = V[j] - V[o]
        cross = np.linalg.norm(np.cross(a, b), axis=1)
        dot = np.einsum("ij,ij->i", a, b)
        cot = dot / np.maximum(cross, 1e-300)
        if clamp:
            cot = np.maximum(cot, 0.0)
        rows += [i, j]
        cols += [j, i]
        vals += [0.5 * cot, 0.5 * cot]
    W = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
    )  # duplicates (the two triangles of an edge) are summed
    W.sum_duplicates()
    if clamp and W.nnz:
        W.data = np.maximum(W.data, 1e-8 * float(np.mean(np.abs(W.data))))
    return W


def _edge_list(weights: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    coo = weights.tocoo()
    return coo.row.astype(np.int64), coo.col.astype(np.int64), coo.data.astype(np.float64)


def arap_energy(
    rest: np.ndarray,
    deformed: np.ndarray,
    weights: sp.csr_matrix,
    rotation_method: str = "fast",
) -> float:
    """ARAP energy of ``deformed`` against ``rest`` with the optimal cell rotations.

    rest, deformed: (V, 3) float, same units (mm); weights: (V, V) from :func:`cotangent_weights`.
    Returns ``sum_i sum_j w_ij ||(p'_i - p'_j) - R_i (p_i - p_j)||^2`` in units^2 (every
    undirected edge appears in both of its vertices' cells).
    """
    P = np.asarray(rest, dtype=np.float64)
    Q = np.asarray(deformed, dtype=np.float64)
    i, j, w = _edge_list(weights)
    e = P[i] - P[j]
    f = Q[i] - Q[j]
    S = np.zeros((P.shape[0], 3, 3))
    np.add.at(S, i, w[:, None, None] * e[:, :, None] * f[:, None, :])
    R = fit_rotations(S, rotation_method)
    r = f - np.einsum("nab,nb->na", R[i], e)
    return float(np.sum(w * np.einsum("na,na->n", r, r)))
