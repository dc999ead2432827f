"""Region-of-interest selection for the deformer: the vertices near the handles that are
free to move. Pure functions on the neutral (rest) mesh."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from .errors import DeformerError

METRICS = ("geodesic", "euclidean")


def mesh_edges(triangles: np.ndarray) -> np.ndarray:
    """Unique undirected edges (E, 2) int64, ``i < j``, of a triangle list (T, 3)."""
    T = np.asarray(triangles, dtype=np.int64)
    e = np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]])
    e.sort(axis=1)
    return np.unique(e, axis=0)


def edge_length_graph(vertices: np.ndarray, triangles: np.ndarray) -> sp.csr_matrix:
    """Symmetric (V, V) csr of edge lengths (units of ``vertices``) for shortest paths."""
    V = np.asarray(vertices, dtype=np.float64)
    e = mesh_edges(triangles)
    length = np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1)
    n = V.shape[0]
    g = sp.coo_matrix((length, (e[:, 0], e[:, 1])), shape=(n, n))
    return (g + g.T).tocsr()


def distances_from(
    vertices: np.ndarray,
    seeds,
    metric: str = "geodesic",
    graph: sp.csr_matrix | None = None,
    triangles: np.ndarray | None = None,
    limit: float = np.inf,
) -> np.ndarray:
    """Distance (V,) float64 of every vertex to the nearest seed vertex, in model units.

    ``geodesic``: shortest path along mesh edges (an upper bound of the true surface distance,
    within a few percent on a regular mesh); needs ``graph`` (from :func:`edge_length_graph`) or
    ``triangles``. ``euclidean``: straight-line distance. Vertices beyond ``limit`` get inf
    (geodesic) so the search stays local.
    """
    V = np.asarray(vertices, dtype=np.float64)
    s = np.asarray(seeds, dtype=np.int64).ravel()
    if s.size == 0:
        raise DeformerError("no seed vertices to measure the ROI from")
    if s.min() < 0 or s.max() >= V.shape[0]:
        raise DeformerError(f"seed vertices out of range 0..{V.shape[0] - 1}")
    if metric == "euclidean":
        d = np.full(V.shape[0], np.inf)
        for i in s:
            d = np.minimum(d, np.linalg.norm(V - V[i], axis=1))
        return d
    if metric != "geodesic":
        raise DeformerError(f"unknown ROI metric {metric!r} (use one of {METRICS})")
    if graph is None:
        if triangles is None:
            raise DeformerError("geodesic distances need the mesh triangles or its edge graph")
        graph = edge_length_graph(V, triangles)
    return dijkstra(graph, directed=False, indices=s, min_only=True, limit=limit)


def roi_within_radius(
    vertices: np.ndarray,
    seeds,
    radius: float,
    metric: str = "geodesic",
    graph: sp.csr_matrix | None = None,
    triangles: np.ndarray | None = None,
) -> np.ndarray:
    """Sorted vertex indices (int64) within ``radius`` (model units, mm) of any seed, seeds
    included; the default ROI of a handle. Raises DeformerError for a radius that is not a
    positive finite number."""
    r = float(radius)
    if not np.isfinite(r) or r <= 0:
        raise DeformerError(f"ROI radius must be a positive number of mm, got {radius!r}")
    d = distances_from(vertices, seeds, metric, graph=graph, triangles=triangles, limit=r)
    return np.flatnonzero(d <= r)
