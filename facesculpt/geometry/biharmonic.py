"""A smooth field over a mesh from its values at a few control vertices: biharmonic interpolation
(the field minimises the squared umbrella Laplacian, ``|L x|^2``, with the control vertices held).
Model-based coding sends the expression basis at control vertices only and the receiver, who has
the mesh, fills in the rest (:mod:`facesculpt.coding.fsc`); the coder and the reenactment rooms share it.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl


def farthest_point_samples(points: np.ndarray, count: int) -> np.ndarray:
    """(m,) int64 indices of ``min(count, N)`` of ``points`` (N, D): vertex 0, then each time the
    point farthest from those taken (Euclidean; ties to the lowest index)."""
    pts = np.asarray(points, np.float64)
    m = min(int(count), len(pts))
    if m <= 0:
        return np.zeros(0, np.int64)
    taken = [0]
    dist = np.linalg.norm(pts - pts[0], axis=1)
    for _ in range(m - 1):
        i = int(np.argmax(dist))
        taken.append(i)
        dist = np.minimum(dist, np.linalg.norm(pts - pts[i], axis=1))
    return np.asarray(taken, np.int64)


def biharmonic_interpolation(triangles: np.ndarray, n_vertices: int, controls: np.ndarray) -> np.ndarray:
    """(V, m) float64 H: the biharmonic field with values c (m,) at the ``controls`` vertices (m,)
    int is ``H @ c`` (exactly c at the controls). ``triangles`` (T, 3) int over ``n_vertices``
    vertices give the umbrella Laplacian (uniform weights); a vertex no control reaches through
    the mesh gets 0. ValueError on repeated or out-of-range controls."""
    V = int(n_vertices)
    ctrl = np.asarray(controls, np.int64)
    if ctrl.size == 0 or ctrl.min() < 0 or ctrl.max() >= V or len(np.unique(ctrl)) != len(ctrl):
        raise ValueError(f"control vertices must be distinct indices in [0, {V})")
    tri = np.asarray(triangles, np.int64)
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    A = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(V, V)).tocsr()
    A = ((A + A.T) > 0).astype(np.float64)
    L = sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A
    Q = (L.T @ L).tocsc()
    free = np.setdiff1d(np.arange(V), ctrl)
    H = np.zeros((V, len(ctrl)))
    H[ctrl, np.arange(len(ctrl))] = 1.0
    if len(free):
        # A tiny diagonal keeps vertices cut off from every control (their rows are 0) solvable.
        Qff = Q[free][:, free] + sp.identity(len(free), format="csc") * 1e-9
        H[free] = -spl.spsolve(Qff.tocsc(), Q[free][:, ctrl].toarray()).reshape(len(free), len(ctrl))
    return H


def control_values(H: np.ndarray, field: np.ndarray) -> np.ndarray:
    """(m, ...) the control values whose interpolation ``H @ values`` (H (V, m) from
    :func:`biharmonic_interpolation`) is closest to ``field`` (V, ...) in least squares."""
    F = np.asarray(field, np.float64)
    values, *_ = np.linalg.lstsq(H, F.reshape(len(F), -1), rcond=None)
    return values.reshape((H.shape[1],) + F.shape[1:])
