"""The meshes the compositor draws: a face's triangles closed
(:func:`facesculpt.geometry.close_holes.close_holes`) and Loop-subdivided
(:func:`facesculpt.geometry.subdivision.loop_subdivision`), built once per triangle set and level
and kept, the level chosen per frame (:func:`.subdivision.levels_for`).

Subdividing costs the renderer per fine triangle (llvmpipe sets up every triangle on the CPU), and
a fine edge much shorter than a pixel rounds no outline further. So with ``max_fine_edge_px`` the
level follows the face's size on screen: the fewest levels (at least one) whose fine edges are that
short. Without it, a mesh gets as many levels as its triangle budget allows, whatever its size.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from facesculpt.geometry.close_holes import close_holes
from facesculpt.geometry.subdivision import loop_subdivision

from .mesh import vertex_rings
from .subdivision import levels_for, median_edge_px


@dataclass(frozen=True)
class RenderMesh:
    """One mesh to draw: ``closed`` (T, 3) int64 coarse triangles, holes closed; ``rings`` (V, V)
    sparse, the vertices within two edges of each; ``S`` (Vf, V) float32 sparse, coarse to fine
    vertices; ``fine`` (4 ** levels, T, 3) int, the k-th child of coarse triangle t; ``levels``;
    ``key`` equal for equal meshes."""

    closed: np.ndarray
    rings: sp.spmatrix
    S: sp.spmatrix
    fine: np.ndarray
    levels: int
    key: tuple


class RenderMeshes:
    """RenderMeshes(levels=None, max_fine_edge_px=None): the render meshes of the triangle sets
    seen (the last four), each at the levels asked: ``levels`` fixed (0-3), else chosen per frame
    for fine edges of at most ``max_fine_edge_px`` pixels on screen, else the triangle budget's
    (:func:`.subdivision.levels_for`). ``last_levels``: the levels of the last mesh given."""

    def __init__(self, levels: int | None = None, max_fine_edge_px: float | None = None):
        if levels is not None and not 0 <= levels <= 3:
            raise ValueError(f"subdivision must be 0 to 3 levels, got {levels}")
        if max_fine_edge_px is not None and not max_fine_edge_px > 0:
            raise ValueError(f"max_fine_edge_px must be positive, got {max_fine_edge_px}")
        self.levels, self.max_fine_edge_px = levels, max_fine_edge_px
        self._closed: dict[tuple, tuple] = {}   # (triangles hash, shape, V) -> (closed, rings, {levels: (S, fine)})
        self.last_levels: int | None = None

    def get(self, triangles: np.ndarray, n_vertices: int, px: np.ndarray) -> RenderMesh:
        """The mesh of ``triangles`` (T, 3) int over ``n_vertices`` vertices, whose pixels are ``px``
        (V, 2). Raises ValueError for triangles that are not (T, 3) integer indices into the vertices."""
        tri = np.asarray(triangles)
        if tri.ndim != 2 or tri.shape[1] != 3 or len(tri) == 0:
            raise ValueError(f"triangles must be (T, 3) with T > 0, got {tri.shape}")
        if not np.issubdtype(tri.dtype, np.integer):
            raise ValueError(f"triangles must be integer indices, got {tri.dtype}")
        key = (hashlib.blake2b(np.ascontiguousarray(tri, np.int64).tobytes(), digest_size=16).digest(),
               tri.shape, n_vertices)
        if key not in self._closed:
            if tri.min() < 0 or tri.max() >= n_vertices:
                raise ValueError(f"triangle indices must lie in [0, {n_vertices}), got [{tri.min()}, {tri.max()}]")
            if len(self._closed) >= 4:
                self._closed.clear()
            closed = close_holes(tri).astype(np.int64)
            self._closed[key] = (closed, vertex_rings(closed, n_vertices, 2), {})
        closed, rings, subdivided = self._closed[key]
        levels = self.levels
        if levels is None:
            levels = levels_for(len(closed))   # the triangle budget's
            if levels > 0 and self.max_fine_edge_px is not None:   # fewer, by the face's size
                levels = levels_for(len(closed), median_edge_px(px, closed), self.max_fine_edge_px, self.last_levels)
        if levels not in subdivided:
            subdivided[levels] = loop_subdivision(closed, n_vertices, levels)
        S, fine = subdivided[levels]
        self.last_levels = levels
        return RenderMesh(closed, rings, S, fine.reshape(-1, len(closed), 3), levels, key + (levels,))
