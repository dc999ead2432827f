"""The mesh an edit is solved on: the model's own mesh, or the same surface refined when the model's
mesh is coarse.

Why: ARAP on a coarse mesh is far from the smooth deformation a preset stands for. On the
468-point face mesh a handle's grip (a share of the ROI radius) holds no vertex but the handle on
the cheeks and the chin, so the skin around it lags behind (a cusp), and the renderer's Loop
subdivision, which averages the handle with its lagging neighbours, shortens the pull further.
So a coarse mesh is solved on its midpoint refinement (the same flat surface, each triangle split
in four, holes closed as the renderer closes them so a hole's rim bends no more freely than skin),
and the model's displacement is the one whose Loop surface, the surface the renderer draws, fits
the refined solution best (least squares). A mesh with enough vertices is solved as it is.

Arrays: rest (V, 3) float mm, triangles (T, 3) int; fine arrays have Vf rows, the model's V
vertices first (vertex v of the model is vertex v of the refined mesh).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import factorized

from facesculpt.geometry.close_holes import close_holes
from facesculpt.geometry.subdivision import loop_subdivision, midpoint_subdivision

#: A mesh with fewer vertices is solved on a refinement with at least this many (the Surrey
#: model's 3448 are dense enough; the face mesh's 468 get one level, 1833 vertices with its holes
#: closed: two levels moved the handles' skin a little further still, at several times the cost).
MIN_SOLVE_VERTICES = 1500
MIN_SOLVE_VERTICES_RANGE = (0, 20000)
MAX_LEVELS = 3


@dataclass(frozen=True)
class SolveMesh:
    """The mesh an edit is solved on (:func:`solve_mesh`): ``rest`` (Vf, 3) float64 mm,
    ``triangles`` (Tf, 3) int64, ``levels`` of refinement (0: the model's mesh itself), ``n`` the
    model's vertex count V, ``refine`` (Vf, V) sparse with ``rest = refine @ model rest`` (each
    fine vertex's share of the model's vertices), ``loop`` (Vf, V) sparse, the renderer's Loop
    subdivision at the same levels."""

    rest: np.ndarray
    triangles: np.ndarray
    levels: int
    n: int
    refine: sp.csr_matrix
    loop: sp.csr_matrix
    _fits: dict = field(default_factory=dict, compare=False)   # moved vertices -> factorised normal equations

    def to_model(self, fine_displacement: np.ndarray) -> np.ndarray:
        """(V, 3) float64 mm: the model displacement whose Loop surface fits ``fine_displacement``
        (Vf, 3) mm in least squares, over the model vertices the solve moved (the others stay
        exactly still, so an edit changes no more of the face than its ROI); on an unrefined mesh,
        the displacement itself."""
        d = np.asarray(fine_displacement, np.float64)
        if self.levels == 0:
            return d.copy()
        moved = np.flatnonzero(np.any(d[: self.n] != 0.0, axis=1))
        out = np.zeros((self.n, 3))
        if moved.size == 0:
            return out
        key = moved.tobytes()
        if key not in self._fits:
            if len(self._fits) >= 4:   # an anchor set's; a drag keeps one
                self._fits.clear()
            A = self.loop[:, moved]
            self._fits[key] = (A, factorized((A.T @ A).tocsc()))
        A, fit = self._fits[key]
        rhs = A.T @ d
        out[moved] = np.column_stack([fit(rhs[:, k]) for k in range(3)])
        return out

    def inside(self, model_vertices: np.ndarray) -> np.ndarray:
        """(Vf,) bool: the fine vertices made only of the given model vertices ((V,) bool or
        indices): an explicit ROI on the model's mesh, on the refined one."""
        mask = np.zeros(self.n, bool)
        mask[model_vertices] = True
        return (self.refine @ (~mask).astype(np.float64)) == 0


def solve_levels(n_vertices: int, n_triangles: int, min_vertices: int = MIN_SOLVE_VERTICES) -> int:
    """Levels of refinement (each about quadruples the vertices; up to :data:`MAX_LEVELS`) that
    bring a mesh of ``n_vertices`` and ``n_triangles`` to at least ``min_vertices`` (0: none)."""
    levels, n, tri = 0, int(n_vertices), int(n_triangles)
    while n < min_vertices and levels < MAX_LEVELS:
        n += (3 * tri) // 2   # one new vertex per edge; a triangle mesh has about 3 T / 2 edges
        tri *= 4
        levels += 1
    return levels


def solve_mesh(rest: np.ndarray, triangles: np.ndarray, min_vertices: int = MIN_SOLVE_VERTICES) -> SolveMesh:
    """The :class:`SolveMesh` of a model's mesh: itself when it has ``min_vertices`` or more
    vertices, else its hole-closed midpoint refinement with enough levels (:func:`solve_levels`)."""
    rest = np.asarray(rest, np.float64)
    tri = np.asarray(triangles, np.int64)
    V = len(rest)
    levels = solve_levels(V, len(tri), min_vertices)
    if levels == 0:
        eye = sp.identity(V, format="csr")
        return SolveMesh(rest, tri, 0, V, eye, eye)
    closed = close_holes(tri).astype(np.int64)
    refine, fine = midpoint_subdivision(closed, V, levels)
    loop, _ = loop_subdivision(closed, V, levels)
    loop = loop.astype(np.float64)
    return SolveMesh(refine @ rest, fine, levels, V, refine, loop)
