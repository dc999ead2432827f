"""The synthetic RGB-D set (issue 49): the realism benchmark's heads rendered with a depth buffer by
its own rasteriser (:mod:`.raster`), through the noise model of a structured-light camera.

The noise model (a Kinect-v1 / PrimeSense-like projector and camera ``BASELINE_MM`` apart):

* axial noise growing with depth and with the angle of incidence (Nguyen, Izadi & Lovell 2012:
  sigma_z = 1.2 + 1.9 (z - 0.4)^2 mm, z in m, plus 0.1 / sqrt(z) * theta^2 / (pi/2 - theta)^2 mm),
  half of its variance independent per pixel and half correlated over a few pixels (the block
  matching window);
* holes: where the surface is seen at a grazing angle (from ``GRAZING_DEG[0]`` on, certain at
  ``GRAZING_DEG[1]``), on dark regions (the pattern is not seen on dark hair or brows: grey below
  ``DARK_LEVEL``), in the projector's shadow beside the head (the background the head hides from
  the projector), and a few random dropouts;
* quantisation: the disparity to 1/8 px (``SUBPIXEL``) and the depth to whole millimetres.

The background is a wall at ``WALL_MM``. Everything is (H, W) images of the scene's 640x480 frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .raster import project, rasterise, render_textured
from .scene import FACING, Scene, rotation

#: Projector-camera baseline, mm; disparity quantisation, px.
BASELINE_MM, SUBPIXEL = 75.0, 1.0 / 8.0
#: Grazing angles of incidence (degrees) from which pixels start to drop out, and all do.
GRAZING_DEG = (65.0, 80.0)
#: Grey level (0..255) below which the pattern is lost (with certainty at 0).
DARK_LEVEL = 45.0
#: Share of pixels that drop out at random; the background wall's distance, mm.
DROPOUT, WALL_MM = 0.005, 1400.0
#: The correlated share of the noise's variance and its correlation length, px.
CORRELATED, CORRELATION_PX = 0.5, 3.0


@dataclass
class RGBDTruth:
    """One frame's truth: depth (H, W) float64 mm noise-free (the wall where no head); cos_incidence
    (H, W) the cosine between the surface normal and the viewing ray (1 on the wall); head (H, W)
    bool where the head covers the wall; vertices (V, 3) camera mm; R (3, 3) model-to-camera rotation."""

    depth: np.ndarray
    cos_incidence: np.ndarray
    head: np.ndarray
    vertices: np.ndarray
    R: np.ndarray


def _vertex_normals(X: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    n = np.zeros_like(X)
    f = np.cross(X[triangles[:, 1]] - X[triangles[:, 0]], X[triangles[:, 2]] - X[triangles[:, 0]])
    for k in range(3):
        np.add.at(n, triangles[:, k], f)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def true_depth(scene: Scene, i: int) -> RGBDTruth:
    """Frame ``i``'s noise-free depth buffer at the frame's own resolution (one sample per pixel,
    at its centre), where the head's soft border is at least half opaque."""
    W, H = scene.background.shape[1], scene.background.shape[0]
    X = scene.to_camera(scene.rest, i)
    px, z = project(scene.K, X)
    frags = rasterise(px, z, scene.triangles, (0, 0, W, H))
    attrs = frags.interpolate(scene.triangles, np.column_stack([_vertex_normals(X, scene.triangles), scene.alpha]))
    head = frags.covered & (attrs[..., 3] >= 0.5)
    depth = np.where(head, frags.depth, WALL_MM)
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    rays = np.dstack([(u - scene.K[0, 2]) / scene.K[0, 0], (v - scene.K[1, 2]) / scene.K[1, 1], np.ones((H, W))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    n = attrs[..., :3] / np.maximum(np.linalg.norm(attrs[..., :3], axis=2, keepdims=True), 1e-12)
    cos = np.where(head, np.abs((n * rays).sum(axis=2)), rays[..., 2])
    yaw, pitch, _ = scene.pose(i)
    return RGBDTruth(depth, cos, head, X, rotation(yaw, pitch) @ FACING)


def projector_shadow(depth: np.ndarray, focal_px: float, baseline_mm: float = BASELINE_MM) -> np.ndarray:
    """(H, W) bool: pixels the projector (``baseline_mm`` to the camera's left, so shadows fall to
    the right of nearer surfaces) cannot light: a nearer pixel at most its disparity difference to the left."""
    disparity = focal_px * baseline_mm / depth
    shadow = np.zeros(depth.shape, bool)
    reach = int(np.ceil(disparity.max() - disparity.min()))
    for k in range(1, reach + 1):
        shadow[:, k:] |= disparity[:, :-k] - disparity[:, k:] > k
    return shadow


def structured_light(truth: RGBDTruth, grey: np.ndarray, focal_px: float, rng: np.random.Generator) -> np.ndarray:
    """(H, W) uint16 mm: the depth a structured-light camera measures of ``truth`` (0: a hole), given
    the frame's grey levels ``grey`` (H, W) 0..255 and the camera's focal length ``focal_px``."""
    z = truth.depth
    theta = np.arccos(np.clip(truth.cos_incidence, 0.0, 1.0))
    zm = z / 1000.0
    sigma = 1.2 + 1.9 * (zm - 0.4) ** 2 + 0.1 / np.sqrt(zm) * theta ** 2 / np.maximum(np.pi / 2 - theta, 1e-3) ** 2
    smooth = cv2.GaussianBlur(rng.standard_normal(z.shape), (0, 0), CORRELATION_PX)
    smooth /= max(float(smooth.std()), 1e-12)
    noise = np.sqrt(1 - CORRELATED) * rng.standard_normal(z.shape) + np.sqrt(CORRELATED) * smooth
    measured = z + sigma * noise
    fb = focal_px * BASELINE_MM
    disparity = np.round(fb / measured / SUBPIXEL) * SUBPIXEL
    measured = fb / np.maximum(disparity, SUBPIXEL)
    graze = np.clip((np.degrees(theta) - GRAZING_DEG[0]) / (GRAZING_DEG[1] - GRAZING_DEG[0]), 0.0, 1.0)
    dark = np.clip(1.0 - grey / DARK_LEVEL, 0.0, 1.0)
    lost = rng.random(z.shape) < np.maximum.reduce([graze, dark, np.full(z.shape, DROPOUT)])
    lost |= projector_shadow(z, focal_px)
    return np.where(lost, 0, np.clip(np.rint(measured), 0, 65535)).astype(np.uint16)


def rgbd_frame(scene: Scene, i: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, RGBDTruth]:
    """Frame ``i``: colour (H, W, 3) uint8 BGR (the realism benchmark's own render), measured depth
    (H, W) uint16 mm aligned to it (same K), and the truth."""
    X = scene.to_camera(scene.rest, i)
    colour = np.clip(np.rint(render_textured(scene.K, X, scene.triangles, scene.texcoords, scene.alpha,
                                             scene.texture, scene.background)), 0, 255).astype(np.uint8)
    truth = true_depth(scene, i)
    grey = cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY).astype(np.float64)
    return colour, structured_light(truth, grey, float(scene.K[0, 0]), rng), truth


def write_rgbd_input(scene: Scene, colours: list, folder, seed: int = 0, fps: float = 25.0):
    """The input ``colours`` (the sequence's frames, (H, W, 3) uint8 BGR) as an RGB-D recording
    ``process`` reads: beside each frame the depth the structured-light camera measures of it
    (:func:`structured_light` of :func:`true_depth`), in a folder of colour + 16-bit depth PNGs
    with the scene's K (pixel centres at integers, as the project's)."""
    from facesculpt.nodes.camera.rgbd_sources import write_rgbd_folder

    K = scene.K.copy()
    K[:2, 2] -= 0.5
    pairs = []
    for i, colour in enumerate(colours):
        grey = cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY).astype(np.float64)
        depth = structured_light(true_depth(scene, i), grey, float(scene.K[0, 0]), np.random.default_rng((seed, i)))
        pairs.append((colour, depth))
    return write_rgbd_folder(folder, pairs, K=K, fps=fps)
