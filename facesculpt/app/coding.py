"""Model-based coding (a talking head at a few kbit/s): a video described by a keyframe once and a
head pose plus a few expression numbers per frame, re-rendered by the compositor.

Encoding. The fitter learns the person's neutral from the first frames (:meth:`Pipeline.calibrate`);
every frame is then fitted, and described by its pose (a similarity from the fitted model-space
shape onto the fitted camera-space mesh: rotation, translation, scale) and its expression
displacement from the neutral (V, 3) mm. The displacements of the whole video are reduced to
``components`` principal components (their mean and basis, int8 per row, go in the header, once); each frame
sends its coefficients. The header also holds the keyframe (the first frame with a face, whole,
as a WebP image: the face's texture and the background as a still; the background is never
updated), its fit and the neutral. Stream layout: :mod:`facesculpt.coding.fsc`; the same parts travel on the
graph's ``coding/key`` and ``coding/frame`` (the encoder and decoder nodes).

Decoding: :class:`facesculpt.nodes.renderer.coded_face.CodedFace` renders each frame from the
keyframe (the face posed and deformed by the frame's parameters, the mouth painted where it opens).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from facesculpt.app.reenactment import inner_lip_ids
from facesculpt.coding.fsc import (
    KEY_QUALITY,
    CodedStream,
    coefficient_steps,
    keyframe_image,
    pack_basis,
    pack_key_arrays,
    read_stream,
    write_stream,
)
from facesculpt.geometry.similarity import similarity_vector
from facesculpt.nodes.camera.intrinsics import FOV_DEG
from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.nodes.reenact.expression_basis import expression_basis, expression_coefficients

#: The neck band of :func:`neck_band` reaches this share of the face's height below its lowest point.
NECK_BAND = 0.35


@dataclass
class Analysis:
    """What the encoder measured of a video: fps, size (w, h), present (F,) bool, pose (F, 7),
    expression (F, V, 3) mm from the neutral (zeros without a face), neutral (V, 3), projected
    (F, V, 2) px of each frame's fit (NaN without a face), key: the keyframe's index, key_fit,
    key_image, triangles (T, 3) of the model."""

    fps: float
    size: tuple
    present: np.ndarray
    pose: np.ndarray
    expression: np.ndarray
    neutral: np.ndarray
    projected: np.ndarray
    key: int
    key_fit: object
    key_image: np.ndarray
    triangles: np.ndarray


def analyse(frames, fps: float, neutral_frames: int = FitterConfig.neutral_frames, fov_deg: float = FOV_DEG,
            progress=None) -> Analysis:
    """Fit every frame of a video; ValueError without a face. ``frames``: a list of (H, W, 3)
    uint8 BGR, or a callable returning a fresh iterator over them (called twice: the neutral's
    pass over the first frames, then every frame), so a long video is never held in memory;
    progress(n): called per frame of the second pass."""
    from itertools import islice

    from facesculpt.app.pipeline import Pipeline

    def fresh():
        return iter(frames()) if callable(frames) else iter(frames)

    with Pipeline("facemesh", fov_deg=fov_deg, fit=FitterConfig(neutral_frames=neutral_frames)) as pipe:
        pipe.calibrate(islice(fresh(), neutral_frames), fps)
        neutral = np.array(pipe.neutral, np.float64)
        present, pose, expression, projected = [], [], [], []
        key, key_fit, key_image, size = -1, None, None, None
        for i, frame in enumerate(fresh()):
            size = (frame.shape[1], frame.shape[0])
            fit = pipe.fit_frame(frame, i / fps)
            if progress is not None:
                progress(1)
            present.append(fit is not None)
            pose.append(np.zeros(7) if fit is None else similarity_vector(fit.model_vertices, fit.vertices))
            expression.append(np.zeros_like(neutral, np.float32) if fit is None
                              else (fit.model_vertices - neutral).astype(np.float32))
            projected.append(np.full((len(neutral), 2), np.nan, np.float32) if fit is None else fit.projected)
            if fit is not None and key < 0:
                key, key_fit, key_image = i, fit, frame
        triangles = np.asarray(pipe.model.triangles)
    if key < 0:
        raise ValueError("no face was found in the video: nothing to code")
    return Analysis(fps, size, np.array(present), np.array(pose), np.array(expression),
                    neutral.astype(np.float32), np.array(projected), key, key_fit, key_image, triangles)


def encode(analysis: Analysis, path, components: int = 12, key_quality: int = KEY_QUALITY) -> dict:
    """Write ``analysis`` as a `.fsc` stream at ``path``; returns its part sizes (bytes).
    key_quality: the keyframe's WebP quality (1..100)."""
    a = analysis
    mean, basis = expression_basis(a.expression[a.present], components)
    coeffs = np.zeros((len(a.present), len(basis)))
    coeffs[a.present] = expression_coefficients(a.expression[a.present], mean, basis)
    f = a.key_fit
    basis_blob, basis_steps = pack_basis(mean, basis, a.triangles, a.neutral)
    key_blob = pack_key_arrays(f.vertices, a.neutral, None if f.K is not None else f.projected)
    header = {"model": "facemesh", "fps": a.fps, "frames": len(a.present), "width": a.size[0],
              "height": a.size[1], "key": a.key, "vertices": int(a.neutral.shape[0]), "components": len(basis),
              "K": None if f.K is None else np.asarray(f.K).tolist(), "coeff_steps": coefficient_steps(coeffs).tolist(),
              "basis_steps": basis_steps.tolist()}
    return write_stream(path, header, keyframe_image(a.key_image, key_quality), key_blob, basis_blob, a.present,
                        a.pose, coeffs)


class Decoder:
    """Renders the frames of a :class:`CodedStream` (:meth:`frame`); :meth:`close` frees GL.
    body_motion: the chin's motion carried over the neck and body below the jaw (else they stay the
    keyframe's; :mod:`facesculpt.nodes.renderer.body_motion`)."""

    def __init__(self, stream: CodedStream, body_motion: bool = True):
        from facesculpt.app.pipeline import load_face_model
        from facesculpt.nodes.renderer.coded_face import CodedFace

        self.stream = stream
        h = stream.header
        model = load_face_model(h["model"])
        key = int(h["key"])
        self.face = CodedFace(h, stream.keyframe, stream.arrays, model.triangles, stream.pose[key],
                              stream.coeffs[key], lips=inner_lip_ids(model), body_motion=body_motion)

    def frame(self, i: int) -> np.ndarray:
        """(H, W, 3) uint8 BGR: frame ``i`` rendered (a frame without a face holds the last one's
        parameters; frames before the keyframe render it with its own)."""
        return self.face.render(bool(self.stream.present[i]), self.stream.pose[i], self.stream.coeffs[i])

    def close(self) -> None:
        self.face.release()


def decode_file(path, body_motion: bool = True) -> tuple[CodedStream, Decoder]:
    """The stream at ``path`` and a :class:`Decoder` for it (``body_motion``: as :class:`Decoder`'s)."""
    from facesculpt.app.pipeline import load_face_model

    stream = read_stream(path, lambda model: load_face_model(model).triangles)
    return stream, Decoder(stream, body_motion)


def face_region_quality(decoded: np.ndarray, original: np.ndarray, projected: np.ndarray) -> tuple[float, float]:
    """(PSNR dB, SSIM) of ``decoded`` against ``original`` (H, W, 3) uint8 in the face region: the
    convex hull of the original frame's fitted face ``projected`` (V, 2) px. SSIM on grey levels
    over the region's bounding box."""
    from skimage.metrics import structural_similarity

    mask = np.zeros(original.shape[:2], np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull(np.round(projected).astype(np.int32)), 1)
    m = mask.astype(bool)
    err = ((decoded.astype(np.float64) - original.astype(np.float64)) ** 2)[m].mean()
    psnr = 10 * np.log10(255.0 ** 2 / max(err, 1e-12))
    ys, xs = np.nonzero(m)
    box = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
    g1 = cv2.cvtColor(decoded, cv2.COLOR_BGR2GRAY)[box]
    g2 = cv2.cvtColor(original, cv2.COLOR_BGR2GRAY)[box]
    return float(psnr), float(structural_similarity(g1, g2, data_range=255))


def neck_band(original_shape: tuple[int, ...], projected: np.ndarray) -> np.ndarray:
    """(H, W) bool: the band below the jaw of a face fitted at ``projected`` (V, 2) px in a frame of
    ``original_shape`` (H, W, ...): as wide as the face's box, from its middle height down to
    ``NECK_BAND`` of its height below its lowest point, outside the face's convex hull (neck, the
    collar and the background beside them)."""
    H, W = original_shape[:2]
    lo, hi = np.nanmin(projected, axis=0), np.nanmax(projected, axis=0)
    band = np.zeros((H, W), np.uint8)
    x0, x1 = int(np.clip(np.floor(lo[0]), 0, W)), int(np.clip(np.ceil(hi[0]) + 1, 0, W))
    y0 = int(np.clip(np.floor(0.5 * (lo[1] + hi[1])), 0, H))
    y1 = int(np.clip(np.ceil(hi[1] + NECK_BAND * (hi[1] - lo[1])) + 1, 0, H))
    band[y0:y1, x0:x1] = 1
    cv2.fillConvexPoly(band, cv2.convexHull(np.round(projected).astype(np.int32)), 0)
    return band.astype(bool)


def region_psnr(decoded: np.ndarray, original: np.ndarray, region: np.ndarray) -> float:
    """PSNR (dB) of ``decoded`` against ``original`` (H, W, 3) uint8 over ``region`` (H, W) bool
    (NaN for an empty region)."""
    if not region.any():
        return float("nan")
    err = ((decoded.astype(np.float64) - original.astype(np.float64)) ** 2)[region].mean()
    return float(10 * np.log10(255.0 ** 2 / max(err, 1e-12)))
