"""Loop subdivision of a triangle mesh as one sparse matrix, and midpoint subdivision in the same
vertex order.

The compositor draws the face as a triangle mesh; with a few hundred vertices an edited outline
(a chin pulled down) shows the mesh's straight edges (docs/architecture.md "Stages", 4). Loop
subdivision (Loop 1987) refines every triangle into four and moves the vertices by fixed linear
weights, so any per-vertex quantity (pixel positions, depth, the displacement) is carried to the
fine mesh by one sparse matrix ``S``: ``fine = S @ coarse``. The matrix depends on the triangles
only, so it is built once per mesh and applied per frame.

Rules (Loop's, with the usual boundary rules): a new vertex on an interior edge (a, b) with
opposite vertices c, d is 3/8 (a + b) + 1/8 (c + d); on a boundary edge it is the midpoint. An
interior old vertex of valence n moves to (1 - n beta) v + beta * sum(neighbours) with
beta = (5/8 - (3/8 + 1/4 cos(2 pi / n))^2) / n; a boundary vertex to 3/4 v + 1/8 (its two
boundary neighbours), so the outline becomes a cubic B-spline of the coarse outline and does
not depend on interior vertices. Vertices on non-manifold edges, with more than two boundary
edges, or in no triangle stay where they are. Every row of ``S`` sums to 1 (affine
invariance: a planar mesh stays planar, a translated mesh is translated).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def _edges(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unique undirected edges (E, 2) (sorted pairs), the edge of each triangle side (T, 3)
    (side k joins corners k and k + 1) and the number of triangles on each edge (E,)."""
    sides = np.stack([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]], axis=1).reshape(-1, 2)
    edges, inverse, counts = np.unique(np.sort(sides, axis=1), axis=0, return_inverse=True,
                                       return_counts=True)
    return edges, inverse.reshape(-1, 3), counts


def loop_step(triangles: np.ndarray, n_vertices: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """One level of Loop subdivision.

    triangles: (T, 3) int vertex indices; n_vertices: V (vertices in no triangle are kept).
    Returns (S, fine_triangles): S (V + E, V) float64 CSR with fine = S @ coarse (the first V
    fine vertices are the moved old ones, then one per edge), fine_triangles (4 T, 3) int64 with
    the winding of the coarse ones.
    """
    tri = np.asarray(triangles, np.int64)
    V = int(n_vertices)
    edges, side_edge, counts = _edges(tri)
    E = len(edges)
    rows, cols, vals = [], [], []

    # Odd (edge) vertices.
    opposite = tri[:, [2, 0, 1]].reshape(-1)          # the corner opposite each side
    side_edge_flat = side_edge.reshape(-1)
    interior = counts[side_edge_flat] == 2
    e_idx = np.arange(E)
    boundary_e = counts != 2
    ends_w = np.where(boundary_e, 0.5, 3.0 / 8.0)
    rows += [V + e_idx, V + e_idx]
    cols += [edges[:, 0], edges[:, 1]]
    vals += [ends_w, ends_w]
    rows.append(V + side_edge_flat[interior])
    cols.append(opposite[interior])
    vals.append(np.full(int(interior.sum()), 1.0 / 8.0))

    # Even (old) vertices: neighbours through the unique edges.
    valence = np.bincount(edges.reshape(-1), minlength=V)
    n_boundary = np.bincount(edges[boundary_e].reshape(-1), minlength=V)
    used = valence > 0
    is_boundary = used & (n_boundary == 2)
    is_interior = used & (n_boundary == 0)
    n = np.maximum(valence, 1).astype(np.float64)
    beta = (5.0 / 8.0 - (3.0 / 8.0 + 0.25 * np.cos(2.0 * np.pi / n)) ** 2) / n
    self_w = np.where(is_interior, 1.0 - n * beta, np.where(is_boundary, 0.75, 1.0))
    rows.append(np.arange(V))
    cols.append(np.arange(V))
    vals.append(self_w)
    for a, b in ((0, 1), (1, 0)):
        v, u = edges[:, a], edges[:, b]
        take_int = is_interior[v]
        rows.append(v[take_int])
        cols.append(u[take_int])
        vals.append(beta[v[take_int]])
        take_bnd = is_boundary[v] & boundary_e
        rows.append(v[take_bnd])
        cols.append(u[take_bnd])
        vals.append(np.full(int(take_bnd.sum()), 1.0 / 8.0))
    # Any other vertex (non-manifold, in no triangle) keeps weight 1 on itself, no neighbours.

    S = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(V + E, V))
    S.sum_duplicates()
    return S, _split(tri, side_edge, V)


def _split(tri: np.ndarray, side_edge: np.ndarray, V: int) -> np.ndarray:
    """(4 T, 3) int64: each triangle of ``tri`` (T, 3) as four, with the new vertex V + e on edge e
    (``side_edge`` (T, 3): the edge of each side, :func:`_edges`), keeping the winding."""
    m = V + side_edge                                 # (T, 3): the new vertex on each side
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    m01, m12, m20 = m[:, 0], m[:, 1], m[:, 2]
    return np.concatenate([
        np.column_stack([a, m01, m20]),
        np.column_stack([m01, b, m12]),
        np.column_stack([m20, m12, c]),
        np.column_stack([m01, m12, m20]),
    ])


def loop_subdivision(triangles: np.ndarray, n_vertices: int, levels: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """``levels`` levels of Loop subdivision as one matrix.

    triangles: (T, 3) int; n_vertices: V; levels >= 0. Returns (S (Vf, V) float32 CSR,
    fine_triangles (T 4^levels, 3) int64); levels = 0 gives the identity and the triangles.
    Raises ValueError on bad triangles or a negative level.
    """
    S, fine = _levels(loop_step, triangles, n_vertices, levels)
    return S.astype(np.float32), fine


def midpoint_step(triangles: np.ndarray, n_vertices: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """One level of midpoint subdivision: :func:`loop_step`'s vertices and fine triangles, the old
    vertices kept where they are and each new one at the middle of its edge (the same flat surface,
    refined). Returns (M (V + E, V) float64 CSR, fine_triangles (4 T, 3) int64)."""
    tri = np.asarray(triangles, np.int64)
    V = int(n_vertices)
    edges, side_edge, _ = _edges(tri)
    E = len(edges)
    rows = np.concatenate([np.arange(V), V + np.arange(E), V + np.arange(E)])
    cols = np.concatenate([np.arange(V), edges[:, 0], edges[:, 1]])
    vals = np.concatenate([np.ones(V), np.full(2 * E, 0.5)])
    return sp.csr_matrix((vals, (rows, cols)), shape=(V + E, V)), _split(tri, side_edge, V)


def midpoint_subdivision(triangles: np.ndarray, n_vertices: int, levels: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """``levels`` levels of :func:`midpoint_step` as one matrix: (M (Vf, V) float64 CSR,
    fine_triangles (T 4^levels, 3) int64), the vertices and triangles of :func:`loop_subdivision`
    at the same levels. Raises ValueError as it does."""
    return _levels(midpoint_step, triangles, n_vertices, levels)


def _levels(step_of, triangles, n_vertices: int, levels: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """``levels`` steps of ``step_of`` (:func:`loop_step` or :func:`midpoint_step`) composed:
    (matrix (Vf, V) float64 CSR, fine triangles (T 4^levels, 3) int64), after checking the input."""
    tri = np.asarray(triangles)
    if tri.ndim != 2 or tri.shape[1] != 3 or not np.issubdtype(tri.dtype, np.integer):
        raise ValueError(f"triangles must be (T, 3) integer indices, got {tri.shape} {tri.dtype}")
    if levels < 0:
        raise ValueError(f"subdivision levels must be >= 0, got {levels}")
    if len(tri) and (tri.min() < 0 or tri.max() >= n_vertices):
        raise ValueError(f"triangle indices must lie in [0, {n_vertices})")
    S = sp.identity(int(n_vertices), format="csr", dtype=np.float64)
    fine = tri.astype(np.int64)
    for _ in range(int(levels)):
        step, fine = step_of(fine, S.shape[0])
        S = (step @ S).tocsr()
    S.sort_indices()
    return S, fine
