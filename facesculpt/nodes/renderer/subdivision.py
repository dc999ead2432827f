"""How many levels of Loop subdivision (:mod:`facesculpt.geometry.subdivision`) the renderer
draws a face with: by a triangle budget, or by the face's size on screen."""

from __future__ import annotations

import numpy as np

#: The longest edge (px on screen) of the render mesh a renderer subdivides to by default: an
#: edited outline's corners are rounded off at that length, and llvmpipe sets up every triangle on
#: the CPU (a finer mesh costs the renderer per triangle for little more rounding).
MAX_FINE_EDGE_PX = 4.0
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
