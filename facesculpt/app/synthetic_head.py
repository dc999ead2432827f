"""A synthetic textured head for renders at known pose: a morphable model's random identity,
textured from a real face in a photo (fitted with the project's landmarks and sparse fitter), its
holes closed, its border faded, before a pinhole camera. The realism benchmark's scene
(``benchmarks/realism/scene.py``) and the landmark calibration's sequences
(:mod:`facesculpt.app.landmark_calibration`) are built from these parts; rendering is
:func:`facesculpt.geometry.raster.render_textured`.

Model space is the model's (the SFM's: mm, x to the subject's left, y up, z out of the face);
camera space OpenCV's (x right, y down, z away, mm).
"""

from __future__ import annotations

import cv2
import numpy as np

from facesculpt.geometry.boundary_loops import boundary_loops

#: Width (mm) over which the mesh's border fades to transparent (a soft hair/skin border).
BORDER_FADE_MM = 8.0
#: Model space -> camera space of a face looking into the camera (OpenCV: y down, z away).
FACING = np.diag([1.0, -1.0, -1.0])


def rotation(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """Camera-space rotation (3, 3): yaw about the camera's y axis after pitch about its x axis."""
    a, b = np.radians(yaw_deg), np.radians(pitch_deg)
    Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    return Ry @ Rx


def intrinsics(size: tuple[int, int], fov_deg: float) -> np.ndarray:
    """(3, 3) pinhole intrinsics of an image ``size`` (W, H) px with a horizontal field of view
    ``fov_deg`` degrees, the principal point at the image's centre."""
    W, H = size
    f = W / 2 / np.tan(np.radians(fov_deg) / 2)
    return np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])


def fit_photo(model, photo: np.ndarray, fov_deg: float = 60.0) -> np.ndarray:
    """Pixel positions (V, 2) of the model's vertices on the face in ``photo`` (BGR): the project's
    landmark detector and sparse fitter (several iterations, no smoothing) on the still image, a
    camera of ``fov_deg`` degrees. RuntimeError when the photo shows no face."""
    return photo_fit(model, photo, fov_deg)[0]


def photo_fit(model, photo: np.ndarray, fov_deg: float = 60.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`fit_photo`'s vertex pixels (V, 2), their depths (V,) mm, and the landmark network's
    68 iBUG points (68, 2) px that were fitted."""
    from facesculpt.geometry import to_ibug68
    from facesculpt.nodes.fitter import FitterConfig, make_fitter
    from facesculpt.nodes.landmarks.detector import LandmarkDetector

    faces = LandmarkDetector().detect(photo)
    if not faces:
        raise RuntimeError("no face found in the texture photo")
    h, w = photo.shape[:2]
    config = FitterConfig(iterations=10, smoothing=False, accumulate_identity=False)
    fitter = make_fitter(model, config, (w, h), intrinsics((w, h), fov_deg))
    pts = to_ibug68(faces[0].points[:, :2].astype(np.float64))
    fit = fitter.fit(pts, [str(i) for i in range(1, 69)])
    return np.asarray(fit.projected, np.float64), np.asarray(fit.vertices, np.float64)[:, 2], pts


def painted_points(uv: np.ndarray, depth: np.ndarray, triangles: np.ndarray, rest: np.ndarray,
                   targets: np.ndarray) -> np.ndarray:
    """(P, 3) model mm: where each texture pixel ``targets`` (P, 2) is painted on the head, given
    the texture coordinates ``uv`` (V, 2) px of its rest vertices (V, 3) and their depths (V,) in
    the photo (the front-most triangle of ``triangles`` (T, 3) that holds the pixel wins); NaN for a
    pixel no triangle holds."""
    tri = np.asarray(triangles, np.int64)
    a, b, c = uv[tri[:, 0]], uv[tri[:, 1]], uv[tri[:, 2]]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    out = np.full((len(targets), 3), np.nan)
    for k, q in enumerate(np.asarray(targets, np.float64)):
        with np.errstate(divide="ignore", invalid="ignore"):
            l0 = ((b[:, 0] - q[0]) * (c[:, 1] - q[1]) - (b[:, 1] - q[1]) * (c[:, 0] - q[0])) / area
            l1 = ((c[:, 0] - q[0]) * (a[:, 1] - q[1]) - (c[:, 1] - q[1]) * (a[:, 0] - q[0])) / area
        lam = np.stack([l0, l1, 1.0 - l0 - l1], axis=1)
        inside = np.flatnonzero((np.abs(area) > 1e-9) & (lam >= -1e-9).all(axis=1))
        if len(inside):
            z = (lam[inside] * depth[tri[inside]]).sum(axis=1)
            best = inside[np.argmin(z)]
            out[k] = lam[best] @ rest[tri[best]]
    return out


def close_holes_with_centres(rest: np.ndarray, triangles: np.ndarray, texcoords: np.ndarray):
    """The mesh (rest (V, 3), triangles (T, 3), texcoords (V, 2)) with every boundary loop but the
    outer one (the mouth, the eyes) closed by a fan around a new centre vertex (the loop's mean
    position and texture coordinate): (rest, triangles, texcoords, outer loop (n,) int64)."""
    loops = boundary_loops(triangles)
    rest, tris, tex = [rest], [triangles], [texcoords]
    n = len(rest[0])
    for loop in loops[1:]:
        rest.append(rest[0][loop].mean(axis=0, keepdims=True))
        tex.append(texcoords[loop].mean(axis=0, keepdims=True))
        # the hole's orientation is the reverse of the loop's boundary edges
        tris.append(np.column_stack([np.roll(loop, -1), loop, np.full(len(loop), n)]))
        n += 1
    return np.concatenate(rest), np.concatenate(tris), np.concatenate(tex), loops[0]


def border_alpha(rest: np.ndarray, border: np.ndarray, fade_mm: float = BORDER_FADE_MM) -> np.ndarray:
    """(V,) alpha: 0 on the ``border`` vertices (the mesh's outer loop), rising smoothly to 1 at
    ``fade_mm`` from them."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(rest[border]).query(rest)
    s = np.clip(d / fade_mm, 0.0, 1.0)
    return s * s * (3 - 2 * s)


def random_identity(model, seed: int, sigma: float = 0.8, components: int = 20) -> np.ndarray:
    """Rest vertices (V, 3) mm: the model's mean plus the first ``components`` shape components
    with coefficients drawn from N(0, sigma²) standard deviations."""
    rng = np.random.default_rng(seed)
    alpha = np.zeros(model.num_shape)
    alpha[:components] = rng.normal(0.0, sigma, components)
    return np.asarray(model.instance(alpha), np.float64)


def procedural_background(seed: int, size: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) uint8 for ``size`` (W, H): smooth coloured noise with a few sharp-edged blocks (a
    room-like clutter)."""
    rng = np.random.default_rng(seed)
    W, H = size
    low = cv2.resize(rng.uniform(40, 220, (6, 8, 3)).astype(np.float32), (W, H), interpolation=cv2.INTER_CUBIC)
    img = low + rng.normal(0, 6, (H, W, 3)).astype(np.float32)
    for _ in range(6):
        x, y = rng.integers(0, W - 60), rng.integers(0, H - 60)
        w, h = rng.integers(30, 200), rng.integers(30, 200)
        img[y:y + h, x:x + w] = rng.uniform(30, 230, 3)
    return np.clip(img, 0, 255).astype(np.uint8)
