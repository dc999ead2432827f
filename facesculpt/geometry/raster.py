"""A small reference rasteriser in numpy: perspective triangles, a z-buffer, perspective-correct
barycentric interpolation of per-vertex attributes, supersampled anti-aliasing. The realism
benchmark's ground truth renders with it (it shares nothing with the OpenGL renderer), and so do
the landmark calibration's sequences (`facesculpt model calibrate`).

Conventions: OpenCV camera space (x right, y down, z away from the camera, mm); pixel centres at
integer + 0.5 (a pixel (i, j) covers [j, j+1) x [i, i+1)); images (H, W, C) float32.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


def project(K: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) float64 (pixel-centre convention: the principal point K[:2, 2] is a
    continuous coordinate) and depths (N,) mm of camera-space points X (N, 3) mm."""
    X = np.asarray(X, np.float64)
    z = X[:, 2]
    uv = X[:, :2] / z[:, None] * np.array([K[0, 0], K[1, 1]]) + K[:2, 2]
    return uv, z


def project_pixels(K: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) float64 of camera-space points X (N, 3) mm in the project's convention (OpenCV:
    pixel centres at integer coordinates), where :func:`project`'s centres are at +0.5."""
    return project(K, X)[0] - 0.5


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


def render_textured(K: np.ndarray, X: np.ndarray, triangles: np.ndarray, texcoords: np.ndarray, alpha: np.ndarray,
                    texture: np.ndarray, background: np.ndarray, ss: int = 3) -> np.ndarray:
    """The mesh X (V, 3) camera-space mm, coloured from ``texture`` (h, w, 3) at per-vertex
    ``texcoords`` (V, 2) texture pixels (pixel-centre convention), each vertex weighted by
    ``alpha`` (V,) in [0, 1] (a soft border), over ``background`` (H, W, 3), supersampled
    ``ss`` x ``ss`` per pixel and box-filtered down. Returns (H, W, 3) float32 in the
    background's value range."""
    H, W = background.shape[:2]
    px, z = project(K, X)
    px_ss = px * ss
    lo = np.floor(px_ss.min(axis=0)).astype(int) - 2
    hi = np.ceil(px_ss.max(axis=0)).astype(int) + 2
    x0 = int(np.clip(lo[0] // ss * ss, 0, W * ss))
    y0 = int(np.clip(lo[1] // ss * ss, 0, H * ss))
    x1 = int(np.clip(-(-hi[0] // ss) * ss, 0, W * ss))
    y1 = int(np.clip(-(-hi[1] // ss) * ss, 0, H * ss))
    out = background.astype(np.float32).copy()
    if x1 <= x0 or y1 <= y0:
        return out
    frags = rasterise(px_ss, z, triangles, (x0, y0, x1, y1))
    attrs = frags.interpolate(triangles, np.column_stack([texcoords, alpha]))
    uv = (attrs[..., :2] - 0.5).astype(np.float32)  # cv2.remap: integer coordinates are pixel centres
    colour = cv2.remap(texture.astype(np.float32), uv[..., 0], uv[..., 1], cv2.INTER_CUBIC,
                       borderMode=cv2.BORDER_REFLECT)
    a = (np.clip(attrs[..., 2], 0.0, 1.0) * frags.covered).astype(np.float32)
    h, w = a.shape
    a_lo = a.reshape(h // ss, ss, w // ss, ss).mean(axis=(1, 3))
    c_lo = (colour * a[..., None]).reshape(h // ss, ss, w // ss, ss, 3).mean(axis=(1, 3))
    win = out[y0 // ss: y1 // ss, x0 // ss: x1 // ss]
    win[:] = c_lo + (1.0 - a_lo[..., None]) * win
    return out


def visible_vertices(K: np.ndarray, X: np.ndarray, triangles: np.ndarray, size: tuple[int, int],
                     tolerance_mm: float = 1.0) -> np.ndarray:
    """(V,) bool: the vertices of X (V, 3) camera space that no nearer surface hides, in an
    image of ``size`` (W, H) (z-buffer at the image's own resolution, depth within
    ``tolerance_mm``)."""
    W, H = size
    px, z = project(K, X)
    frags = rasterise(px, z, triangles, (0, 0, W, H))
    j = np.floor(px[:, 0]).astype(int)
    i = np.floor(px[:, 1]).astype(int)
    inside = (j >= 0) & (j < W) & (i >= 0) & (i < H)
    vis = np.zeros(len(X), bool)
    d = frags.depth[i[inside], j[inside]]
    vis[inside] = z[inside] <= d + tolerance_mm
    return vis
