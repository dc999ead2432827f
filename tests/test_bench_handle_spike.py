"""bench_handle_spike's measure of the spike a handle pulls (benchmarks/bench_handle_spike.py), on
a flat grid: a vertex pulled alone is all spike, a patch moved with it none."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from benchmarks.bench_handle_spike import median_edge_at, spike_of


def grid(n: int = 9, step: float = 2.0):
    """An n x n grid of vertices ``step`` mm apart in the plane z = 0, two triangles a cell."""
    ys, xs = np.mgrid[0:n, 0:n]
    rest = np.column_stack([xs.ravel() * step, ys.ravel() * step, np.zeros(n * n)]).astype(np.float64)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    return rest, np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])


def test_a_vertex_pulled_alone_is_all_spike_and_a_patch_moved_with_it_none():
    rest, tri = grid()
    S = sp.identity(len(rest), format="csr")
    h = 40  # the middle vertex
    alone = rest.copy()
    alone[h, 2] += 5.0
    spike, normal = spike_of(S, tri, rest, alone, h)
    assert np.isclose(spike, 1.0) and normal > 60.0   # 5 mm up over 2 mm edges: steep faces
    patch = rest.copy()
    near = np.linalg.norm(rest - rest[h], axis=1) < 5.0
    patch[near, 2] += 5.0
    spike, normal = spike_of(S, tri, rest, patch, h)
    assert spike == 0.0 and normal < 1e-6
    assert np.isclose(median_edge_at(rest, tri, h), 2.0)
