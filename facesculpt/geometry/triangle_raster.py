"""Z-buffered rasterisation of a triangle mesh on the CPU, in numpy: the visible triangle, its
perspective-correct barycentric weights and the depth at every pixel of a window. Arrays in,
arrays out; used where a depth image of a mesh is wanted without a GL context (the edited depth
of :mod:`facesculpt.nodes.renderer.edited_depth`, the realism benchmark's reference renderer).

Conventions: pixels (V, 2) with pixel centres at integer + 0.5 (a pixel (i, j) covers [j, j+1) x
[i, i+1)); the project's pixels (centres at integers, :mod:`.projection`) are these minus 0.5.
Depths in the caller's units (mm), > 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Fragments:
    """What a rasterisation leaves per (supersampled) pixel of a window.

    tri (h, w) int64: the visible triangle (-1: none); bary (h, w, 3) float64
    perspective-correct barycentric weights of its vertices; depth (h, w) float64 mm (inf where
    empty); origin (x0, y0): the window's top-left pixel in the supersampled image."""

    tri: np.ndarray
    bary: np.ndarray
    depth: np.ndarray
    origin: tuple[int, int]

    @property
    def covered(self) -> np.ndarray:
        return self.tri >= 0

    def interpolate(self, triangles: np.ndarray, attributes: np.ndarray) -> np.ndarray:
        """Per-vertex attributes (V, C) interpolated at every covered pixel: (h, w, C) float64,
        zero where empty."""
        attributes = np.asarray(attributes, np.float64).reshape(len(attributes), -1)
        out = np.zeros(self.tri.shape + (attributes.shape[1],))
        m = self.covered
        corners = attributes[triangles[self.tri[m]]]  # (n, 3, C)
        out[m] = np.einsum("nk,nkc->nc", self.bary[m], corners)
        return out


def _candidates(px: np.ndarray, tris: np.ndarray, window: tuple[int, int, int, int]):
    """Every (triangle, pixel) pair whose pixel centre lies in the triangle's bounding box,
    clipped to ``window`` (x0, y0, x1, y1): (triangle index, x, y) int64 arrays."""
    x0, y0, x1, y1 = window
    corners = px[tris]  # (T, 3, 2)
    lo = np.floor(corners.min(axis=1) - 0.5).astype(np.int64) + 1
    hi = np.floor(corners.max(axis=1) - 0.5).astype(np.int64)
    lo = np.maximum(lo, [x0, y0])
    hi = np.minimum(hi, [x1 - 1, y1 - 1])
    w = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0)
    h = np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    n = w * h
    t = np.repeat(np.arange(len(tris)), n)
    start = np.cumsum(n) - n
    k = np.arange(n.sum()) - np.repeat(start, n)
    ww = np.maximum(w[t], 1)
    return t, lo[t, 0] + k % ww, lo[t, 1] + k // ww


def rasterise(px: np.ndarray, z: np.ndarray, triangles: np.ndarray, window: tuple[int, int, int, int]) -> Fragments:
    """Z-buffered rasterisation of ``triangles`` (T, 3) over vertices at pixels ``px`` (V, 2)
    with depths ``z`` (V,) mm (> 0), within ``window`` (x0, y0, x1, y1) of the image. A pixel
    belongs to a triangle when its centre lies inside it (edges included); the nearest wins."""
    tris = np.asarray(triangles, np.int64)
    z = np.asarray(z, np.float64)
    ok = np.all(z[tris] > 1e-6, axis=1)
    tri_ids = np.nonzero(ok)[0]
    t_local, x, y = _candidates(px, tris[tri_ids], window)
    t = tri_ids[t_local]
    a, b, c = (px[tris[t, i]] for i in range(3))
    cx, cy = x + 0.5, y + 0.5
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    w0 = (b[:, 0] - cx) * (c[:, 1] - cy) - (b[:, 1] - cy) * (c[:, 0] - cx)
    w1 = (c[:, 0] - cx) * (a[:, 1] - cy) - (c[:, 1] - cy) * (a[:, 0] - cx)
    with np.errstate(divide="ignore", invalid="ignore"):
        l0, l1 = w0 / area, w1 / area
    l2 = 1.0 - l0 - l1
    eps = -1e-9
    inside = (np.abs(area) > 1e-12) & (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
    t, x, y, lam = t[inside], x[inside], y[inside], np.stack([l0, l1, l2], 1)[inside]
    inv_z = 1.0 / z[tris[t]]  # (n, 3)
    pc = lam * inv_z
    denom = pc.sum(axis=1)
    depth = 1.0 / denom
    bary = pc / denom[:, None]
    x0, y0, x1, y1 = window
    h, w = y1 - y0, x1 - x0
    pix = (y - y0) * w + (x - x0)
    order = np.lexsort((depth, pix))
    first = order[np.r_[True, pix[order][1:] != pix[order][:-1]]] if len(order) else order
    tri_img = np.full(h * w, -1, np.int64)
    bary_img = np.zeros((h * w, 3))
    depth_img = np.full(h * w, np.inf)
    tri_img[pix[first]] = t[first]
    bary_img[pix[first]] = bary[first]
    depth_img[pix[first]] = depth[first]
    return Fragments(tri_img.reshape(h, w), bary_img.reshape(h, w, 3), depth_img.reshape(h, w), (x0, y0))
