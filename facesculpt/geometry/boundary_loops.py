"""The boundary loops of a triangle mesh (the outline and the holes of an open face mesh)."""

from __future__ import annotations

import numpy as np


def boundary_loops(triangles: np.ndarray) -> list[np.ndarray]:
    """The closed boundary loops of a triangle mesh, longest first.

    triangles: (T, 3) int vertex indices. Returns a list of (n,) int64 vertex-index loops
    (each vertex once, in order along the boundary). Edges used by exactly one triangle
    are boundary edges; a non-manifold boundary vertex (several boundary edges) is
    followed greedily, which still yields closed loops for the meshes used here.
    """
    tri = np.asarray(triangles, np.int64)
    if tri.ndim != 2 or tri.shape[1] != 3:
        raise ValueError(f"triangles must be (T, 3), got {tri.shape}")
    # Directed edges of every triangle; a boundary edge has no opposite twin.
    directed = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    key = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    boundary = directed[counts[inverse.ravel()] == 1]
    successors: dict[int, list[int]] = {}
    for a, b in boundary:
        successors.setdefault(int(a), []).append(int(b))
    loops = []
    while successors:
        start = next(iter(successors))
        loop = [start]
        cur = start
        while True:
            nxts = successors.get(cur)
            if not nxts:
                break
            nxt = nxts.pop()
            if not nxts:
                del successors[cur]
            if nxt == start:
                break
            loop.append(nxt)
            cur = nxt
        if len(loop) >= 3:
            loops.append(np.array(loop, np.int64))
    loops.sort(key=len, reverse=True)
    return loops
