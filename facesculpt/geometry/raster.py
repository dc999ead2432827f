"""A small reference rasteriser in numpy: perspective triangles, a z-buffer, perspective-correct
barycentric interpolation of per-vertex attributes, supersampled anti-aliasing. The realism
benchmark's ground truth renders with it (it shares nothing with the OpenGL renderer), and so do
the landmark calibration's sequences (`facesculpt model calibrate`).

Conventions: OpenCV camera space (x right, y down, z away from the camera, mm); pixel centres at
integer + 0.5 (a pixel (i, j) covers [j, j+1) x [i, i+1)); images (H, W, C) float32.
"""

from __future__ import annotations

import cv2
import numpy as np

from facesculpt.geometry.triangle_raster import Fragments, rasterise  # noqa: F401 (Fragments: re-exported)


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
