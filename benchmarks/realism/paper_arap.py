"""The ground-truth edit as the paper's deformation: Sorkine & Alexa's as-rigid-as-possible
surface modelling solved by libigl (``igl.arap_precomputation`` / ``igl.arap_solve``, its
default energy for a triangle mesh: spokes and rims), each handle a single vertex moved by its
offset (no grip), the surface within a geodesic ROI around the handles following, every vertex
outside it fixed
(``bench_realism.py --truth-edit paper``). Neither the project's deformer nor the benchmark's
own solver (:mod:`.arap_truth`) is used.

The ROI: the vertices whose exact surface distance (``igl.exact_geodesic``) from a handle is
within ``radius`` mm.

libigl's spokes-only energy (the cotangent weights are not clamped) does not hold on this mesh:
with the chin's 45 mm ROI, the mesh's free outline beside the chin swings 30 mm for a 9.5 mm
pull; the spokes-and-rims energy is stable there.

Arrays: rest (V, 3) float mm, triangles (T, 3) int, displacements (V, 3) float mm.
"""

from __future__ import annotations

import numpy as np

TOLERANCE_MM = 1e-5    # the solve stops when no vertex moves this far in a round of iterations
ROUND_ITERATIONS = 50  # libigl local/global iterations per round
MAX_ROUNDS = 40


def geodesic_distances(rest: np.ndarray, triangles: np.ndarray, handles: list[int]) -> np.ndarray:
    """(V,): each vertex's exact surface distance (mm) from the nearest of ``handles``."""
    import igl

    V = np.ascontiguousarray(rest, np.float64)
    F = np.ascontiguousarray(triangles, np.int64)
    return np.asarray(igl.exact_geodesic(V, F, VS=np.asarray(handles, np.int64), VT=np.arange(len(V), dtype=np.int64)))


def paper_displacement(rest: np.ndarray, triangles: np.ndarray, handles: dict[int, np.ndarray],
                       radius: float) -> np.ndarray:
    """The displacement (V, 3) mm of ``rest`` when each handle vertex of ``handles`` (vertex ->
    offset (3,) mm) alone is moved by its offset and the ROI of ``radius`` mm (geodesic) deforms
    as rigidly as possible (libigl ARAP, spokes energy, iterated until no vertex moves
    ``TOLERANCE_MM``)."""
    import igl

    V = np.ascontiguousarray(rest, np.float64)
    F = np.ascontiguousarray(triangles, np.int64)
    idx = np.array(list(handles), np.int64)
    roi = geodesic_distances(V, F, list(idx)) <= radius
    roi[idx] = True
    fixed = np.flatnonzero(~roi)
    b = np.concatenate([idx, fixed]).astype(np.int32)
    bc = np.concatenate([V[idx] + np.array([handles[h] for h in idx], np.float64), V[fixed]])
    data = igl.ARAPData()
    data.energy = igl.ARAP_ENERGY_TYPE_SPOKES_AND_RIMS
    data.max_iter = ROUND_ITERATIONS
    igl.arap_precomputation(V, F, 3, b, data)
    U = V.copy()
    U[b] = bc
    for _ in range(MAX_ROUNDS):
        new = np.asarray(igl.arap_solve(bc, data, U))
        moved = np.abs(new - U).max()
        U = new
        if moved < TOLERANCE_MM:
            break
    return U - V
