"""Image-based rendering from keyframes (issue 18, seed 003): stored views of the same head at
other poses, used where the current frame sees the face badly from the view being rendered.

As the head turns during a video, :class:`KeyframeViews` keeps a small set of frames of it at
distinct poses (a new one when the head's rotation differs by more than ``spacing_deg`` from every
stored one; the oldest within ``spacing_deg`` of it replaced after ``refresh_frames``), each with
its fitted vertices (camera space), their pixels and how well that frame saw each vertex
(:attr:`.atlas_raster.AtlasRasterizer.vertex_quality`: frontality, 0 where hidden). For a frame
whose edit turns the head (the deformed vertices' rotation from the fitted ones, by Kabsch), the
stored view closest to the rendered one is chosen when it is closer, by ``MARGIN_DEG``, than the
current frame's own view; its colours are sampled through a second source map (the deformed mesh
drawn with, per vertex, the offset to the keyframe's pixel) and blended in per pixel with the
weight, interpolated from the vertices, by which the keyframe sees the surface better than the
current frame (``(q_key - q_now) / QUALITY_GAIN``, clipped to [0, 1]).

Texture moves with the vertices, so a keyframe with another expression still maps skin onto
skin; the mouth's interior and the eyes (open or closed) are not corrected, and the keyframe's
lighting is used as it was.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from facesculpt.geometry import point_bounds

from .warp import covered_pixels, warp_frame

#: A keyframe is used only when its view is this much closer (degrees) than the current frame's.
MARGIN_DEG = 2.0
#: A keyframe keeps the face's box grown by this share of its larger side (its crop).
CROP_MARGIN = 0.1
#: Quality (frontality) gain of the keyframe over the current frame at which it fully takes over.
QUALITY_GAIN = 0.3


@dataclass
class Keyframe:
    """A stored view: ``image`` (h, w, 3) uint8 the frame's crop around the face, whose top-left
    pixel is the frame pixel ``origin`` (x, y); ``vertices`` (V, 3) camera space; ``pixels`` (V, 2)
    frame px; ``quality`` (V,) float32 in [0, 1]; ``frame`` its index."""

    image: np.ndarray
    origin: tuple[int, int]
    vertices: np.ndarray
    pixels: np.ndarray
    quality: np.ndarray
    frame: int


def rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (degrees) of the rotation that best maps point set ``a`` (N, 3) onto ``b`` (N, 3)
    after centring both (Kabsch; scale and translation ignored)."""
    A = np.asarray(a, np.float64) - np.mean(a, axis=0)
    B = np.asarray(b, np.float64) - np.mean(b, axis=0)
    U, _, Vt = np.linalg.svd(A.T @ B)
    d = np.sign(np.linalg.det(U @ Vt))
    R = (U @ np.diag([1.0, 1.0, d]) @ Vt).T
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


class KeyframeViews:
    """KeyframeViews(spacing_deg=5, max_keyframes=24, refresh_frames=150): the stored views of one
    face (:meth:`offer` every frame, :meth:`choose` per rendered view, :meth:`reset` for a new face)."""

    def __init__(self, spacing_deg: float = 5.0, max_keyframes: int = 24, refresh_frames: int = 150):
        if spacing_deg <= 0 or max_keyframes < 1 or refresh_frames < 1:
            raise ValueError("spacing_deg must be > 0, max_keyframes and refresh_frames >= 1")
        self.spacing_deg, self.max_keyframes, self.refresh_frames = float(spacing_deg), int(max_keyframes), int(refresh_frames)
        self.keyframes: list[Keyframe] = []
        self.frames = 0
        self.used: Keyframe | None = None     # the keyframe the last choose picked

    def reset(self) -> None:
        self.keyframes, self.frames, self.used = [], 0, None

    def offer(self, image: np.ndarray, vertices: np.ndarray, pixels: np.ndarray, quality: np.ndarray) -> bool:
        """Consider the current frame as a keyframe: ``image`` (H, W, 3) uint8 (a crop around the face
        is copied when stored), its fitted ``vertices`` (V, 3) camera space, their ``pixels`` (V, 2)
        and ``quality`` (V,); True when it was stored. A face with another vertex count resets the store."""
        self.frames += 1
        if self.keyframes and len(self.keyframes[0].vertices) != len(vertices):
            self.reset()
        angles = [rotation_angle_deg(k.vertices, vertices) for k in self.keyframes]
        near = int(np.argmin(angles)) if angles else -1
        if near >= 0 and angles[near] <= self.spacing_deg:
            if self.frames - self.keyframes[near].frame < self.refresh_frames or angles[near] > 0.5 * self.spacing_deg:
                return False
            del self.keyframes[near]          # an old view of this pose: take the fresher one
        elif len(self.keyframes) >= self.max_keyframes:
            del self.keyframes[int(np.argmin([k.frame for k in self.keyframes]))]
        px = np.asarray(pixels, np.float64)
        lo, hi = point_bounds(px)
        pad = CROP_MARGIN * float(np.max(hi - lo)) + 4.0   # the sampling kernel reads a few pixels around
        h, w = image.shape[:2]
        x0, y0 = max(0, int(lo[0] - pad)), max(0, int(lo[1] - pad))
        x1, y1 = min(w, int(hi[0] + pad) + 1), min(h, int(hi[1] + pad) + 1)
        if x1 - x0 < 2 or y1 - y0 < 2:
            return False
        self.keyframes.append(Keyframe(image[y0:y1, x0:x1].copy(), (x0, y0), np.asarray(vertices, np.float64).copy(),
                                       px.copy(), np.asarray(quality, np.float32).copy(), self.frames))
        return True

    def choose(self, fitted: np.ndarray, deformed: np.ndarray) -> Keyframe | None:
        """The stored view closest to the ``deformed`` (V, 3) head's view, when it is closer by
        MARGIN_DEG than the current frame's (``fitted`` (V, 3)); None otherwise (no turn, or no
        better view stored). Sets :attr:`used`."""
        self.used = None
        if not self.keyframes:
            return None
        own = rotation_angle_deg(fitted, deformed)
        if own <= MARGIN_DEG:
            return None
        angles = [rotation_angle_deg(k.vertices, deformed) for k in self.keyframes]
        best = int(np.argmin(angles))
        if angles[best] < own - MARGIN_DEG:
            self.used = self.keyframes[best]
        return self.used


def keyframe_weights(key_quality: np.ndarray, now_quality: np.ndarray) -> np.ndarray:
    """(V,) float32 in [0, 1]: how much of each vertex's colour comes from the keyframe: the gain of
    its quality over the current frame's, over QUALITY_GAIN."""
    gain = np.asarray(key_quality, np.float32) - np.asarray(now_quality, np.float32)
    return np.clip(gain / QUALITY_GAIN, 0.0, 1.0).astype(np.float32)


def blend_keyframe(warped: np.ndarray, maps, S, fine: np.ndarray, draw_tris: np.ndarray, n_moving: int,
                   box: tuple[int, int, int, int], block: tuple[slice, slice], changed: np.ndarray,
                   chosen: tuple, interpolation: str) -> int | None:
    """Blend the chosen keyframe into ``warped`` ((h', w', 3) uint8, the sampled ``block`` of the
    work ``box``, in place): the deformed mesh drawn once more by ``maps`` (the compositor's
    :class:`.source_map.SourceMapRenderer`, with extras) with, per fine vertex (``S`` the coarse-to-fine
    matrix, ``fine`` (Vf, >= 3) px and depth of the fine vertices, ``draw_tris`` / ``n_moving`` as
    drawn before), the offset to its keyframe pixel and its weight; the keyframe image sampled
    there and blended in by the interpolated weight over the ``changed`` (h, w) bool pixels.
    ``chosen``: (:class:`Keyframe`, (V,) weights). Returns the keyframe's frame index, or None
    when it gave no pixel."""
    key, weights = chosen
    kf = S @ np.column_stack([key.pixels, weights]).astype(np.float32)
    extra = np.zeros((len(kf), 4), np.float32)
    extra[:, 0] = kf[:, 2]
    maps.draw(fine[:, 0:2], fine[:, 2], kf[:, :2] - fine[:, 0:2], draw_tris, n_moving, box, extra)
    key_offsets, _ = maps.read(box)
    w = maps.read_extra(box)[block][..., 0] * changed[block] * covered_pixels(key_offsets[block])
    if not (w > 0).any():
        return None
    rows, cols = block
    origin = (box[0] + cols.start - key.origin[0], box[1] + rows.start - key.origin[1])  # in the crop
    sampled = warp_frame(key.image, key_offsets[block], origin, interpolation)
    w = np.clip(w, 0.0, 1.0).astype(np.float32)
    np.copyto(warped, cv2.blendLinear(sampled, warped, w, 1.0 - w), where=(w > 0)[..., None])
    return key.frame
