"""The depth image of an edited face (issue 49): what an RGB-D camera would have measured had the
face been the edited one. Arrays in, arrays out.

Both meshes, the fitted one and the deformed one (the edit merged in, paper Eq. 5; a pose edit's
turn included), are rasterised into the depth camera (through the depth-to-colour transform and
the depth image's own K, :mod:`facesculpt.geometry.triangle_raster`). Where the edit changed the
surface (the two depths differ, or one mesh covers a pixel the other does not):

* a pixel the camera measured on the face (within ``FACE_GATE_MM`` of the fitted surface) gets
  the deformed surface's depth plus what the camera measured off the fitted one there (the
  sensor's noise and the detail the model lacks are kept, at the pixel: they are not carried with
  the surface's sideways motion);
* a pixel the edited face newly covers gets its depth, unless the camera measured something in
  front of it there (a hand stays in front);
* a face pixel the edited face no longer covers becomes 0 (no measurement): what lies behind the
  face there was never measured;
* a hole (0) stays a hole, and something the camera measured in front of the face (farther than
  the gate from the fitted surface: a hand, hair) or behind it (the background past a fitted
  outline that lies outside the real one) is kept as it was.

Everywhere else the depth is the input's, bit for bit.
"""

from __future__ import annotations

import numpy as np

from facesculpt.geometry.triangle_raster import rasterise

#: A measured pixel is the face's when it lies within this distance (mm) of the fitted surface.
FACE_GATE_MM = 15.0
#: The edit changed a pixel's surface when the deformed depth differs by more than this (mm).
CHANGED_MM = 0.05


def mesh_depth(vertices: np.ndarray, triangles: np.ndarray, depth_K: np.ndarray, size: tuple[int, int],
               depth_to_color: np.ndarray | None = None) -> np.ndarray:
    """(H, W) float64 mm: the depth along the depth camera's axis of the mesh ``vertices`` (V, 3)
    colour-camera mm, ``triangles`` (T, 3), seen by a depth camera of ``size`` (W, H) px and
    intrinsics ``depth_K`` (3, 3) px (pixel centres at integers), placed by ``depth_to_color``
    (4, 4) mm (None: the colour camera itself); inf where the mesh covers no pixel centre."""
    W, H = size
    X = np.asarray(vertices, np.float64)
    T = depth_to_color
    if T is not None:
        T = np.asarray(T, np.float64)
        X = (X - T[:3, 3]) @ T[:3, :3]
    out = np.full((H, W), np.inf)
    z = X[:, 2]
    if not np.any(z > 1e-6):
        return out
    Kd = np.asarray(depth_K, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        px = X[:, :2] / z[:, None] * [Kd[0, 0], Kd[1, 1]] + Kd[:2, 2] + 0.5  # the rasteriser's centres: +0.5
    seen = (z > 1e-6) & np.all(np.isfinite(px), axis=1)
    lo = np.floor(px[seen].min(axis=0)).astype(np.int64)
    hi = np.ceil(px[seen].max(axis=0)).astype(np.int64) + 1
    x0, y0 = max(0, lo[0]), max(0, lo[1])
    x1, y1 = min(W, hi[0]), min(H, hi[1])
    if x1 <= x0 or y1 <= y0:
        return out
    tris = np.asarray(triangles, np.int64)
    tris = tris[np.all(seen[tris], axis=1)]
    frags = rasterise(np.where(seen[:, None], px, 0.0), np.where(seen, z, 1.0), tris, (x0, y0, x1, y1))
    out[y0:y1, x0:x1] = frags.depth
    return out


def edited_depth(depth: np.ndarray, depth_K: np.ndarray, fitted: np.ndarray, deformed: np.ndarray,
                 triangles: np.ndarray, depth_to_color: np.ndarray | None = None) -> np.ndarray:
    """(DH, DW) uint16 mm: ``depth`` (DH, DW) uint16 mm (0: no measurement) as the camera would
    have measured the face ``deformed`` (V, 3) colour-camera mm in place of ``fitted`` (V, 3), the
    face fitted to this frame (see the module's rules); ``depth_K`` (3, 3) px and
    ``depth_to_color`` (4, 4) mm or None as in :func:`mesh_depth`."""
    depth = np.asarray(depth)
    if depth.dtype != np.uint16 or depth.ndim != 2:
        raise ValueError("the depth image must be (H, W) uint16 mm")
    size = (depth.shape[1], depth.shape[0])
    z_fit = mesh_depth(fitted, triangles, depth_K, size, depth_to_color)
    z_def = mesh_depth(deformed, triangles, depth_K, size, depth_to_color)
    on_fit, on_def = np.isfinite(z_fit), np.isfinite(z_def)
    both = on_fit & on_def
    changed = on_fit ^ on_def
    changed[both] = np.abs(z_def[both] - z_fit[both]) > CHANGED_MM
    if not changed.any():
        return depth.copy()
    d = depth.astype(np.float64)
    measured = depth > 0
    with np.errstate(invalid="ignore"):
        residual = np.where(on_fit & measured, d - z_fit, np.inf)
    face = np.abs(residual) < FACE_GATE_MM
    out = d.copy()
    moved = changed & face & on_def
    out[moved] = z_def[moved] + residual[moved]
    new = changed & ~on_fit & on_def & (~measured | (d > z_def))
    out[new] = z_def[new]
    out[changed & face & ~on_def] = 0.0
    return np.clip(np.rint(out), 0, 65535).astype(np.uint16)
