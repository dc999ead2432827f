"""Loop subdivision of the render mesh as one sparse matrix (docs/architecture.md "Stages", 4).

The compositor draws the face as a triangle mesh; with a few hundred vertices an edited outline
(a chin pulled down) shows the mesh's straight edges. Loop subdivision (Loop 1987) refines
every triangle into four and moves the vertices by fixed linear weights, so any per-vertex
quantity (pixel positions, depth, the displacement) is carried to the fine mesh by one sparse
matrix ``S``: ``fine = S @ coarse``. The matrix depends on the triangles only, so it is built
once per mesh and applied per frame.

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
    m = V + side_edge                                 # (T, 3): the new vertex on each side
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    m01, m12, m20 = m[:, 0], m[:, 1], m[:, 2]
    fine = np.concatenate([
        np.column_stack([a, m01, m20]),
        np.column_stack([m01, b, m12]),
        np.column_stack([m20, m12, c]),
        np.column_stack([m01, m12, m20]),
    ])
    return S, fine


def loop_subdivision(triangles: np.ndarray, n_vertices: int, levels: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """``levels`` levels of Loop subdivision as one matrix.

    triangles: (T, 3) int; n_vertices: V; levels >= 0. Returns (S (Vf, V) float32 CSR,
    fine_triangles (T 4^levels, 3) int64); levels = 0 gives the identity and the triangles.
    Raises ValueError on bad triangles or a negative level.
    """
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
        step, fine = loop_step(fine, S.shape[0])
        S = (step @ S).tocsr()
    S.sort_indices()
    return S.astype(np.float32), fine


LEVEL_HYSTERESIS = 0.15  # the last frame's levels are kept while its fine edges are within this share of the limit


def median_edge_px(px: np.ndarray, triangles: np.ndarray, samples: int = 512) -> float:
    """Median length (pixels) of the edges of ``triangles`` (T, 3) int at vertex pixels ``px``
    (V, 2), over about ``samples`` triangles taken evenly from the list."""
    tri = triangles[:: max(len(triangles) // samples, 1)]
    d = px[tri] - px[np.roll(tri, 1, axis=1)]
    return float(np.median(np.hypot(d[..., 0], d[..., 1])))


def levels_for(n_triangles: int, edge_px: float | None = None, max_fine_edge_px: float | None = None,
               current: int | None = None, max_triangles: int = 16384, max_levels: int = 2) -> int:
    """Loop levels for a mesh of ``n_triangles`` (each level multiplies them by 4).

    The budget: the most levels (up to ``max_levels``) that keep the fine mesh within
    ``max_triangles``; 0 for a mesh already that large. Given the mesh's median edge on screen
    ``edge_px`` (pixels, :func:`median_edge_px`) and ``max_fine_edge_px``: the fewest levels within
    the budget, at least one, whose fine edges (``edge_px / 2 ** levels``) are at most
    ``max_fine_edge_px``. ``current``, the levels the last frame used, stays while its fine edges
    are within :data:`LEVEL_HYSTERESIS` of that limit, so a face at the threshold does not switch
    back and forth."""
    budget = 0
    while budget < max_levels and n_triangles * 4 ** (budget + 1) <= max_triangles:
        budget += 1
    if edge_px is None or max_fine_edge_px is None or budget == 0:
        return budget
    limit = float(max_fine_edge_px)
    levels = 1
    while levels < budget and edge_px / 2 ** levels > limit:
        levels += 1
    if current is not None and 1 <= current <= budget and current != levels:
        coarse_enough = edge_px / 2 ** current <= limit * (1 + LEVEL_HYSTERESIS)
        fine_enough = current == 1 or edge_px / 2 ** (current - 1) > limit * (1 - LEVEL_HYSTERESIS)
        if coarse_enough and fine_enough:
            return current
    return levels
