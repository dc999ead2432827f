"""The performance-driven avatar: a driving face's expression animates a source face.

The source (a photo, or a video's first frame) is fitted once: its fit and the neutral the fitter
learns from it (that very frame). The driving video runs through the usual landmarks and fitting
(:class:`facesculpt.app.pipeline.Pipeline`), whose fitter first learns the driver's own neutral
from its first frames (:meth:`Pipeline.calibrate`). Each driving frame's expression displacement
is its fitted shape minus that neutral, in model space (mm; both faces are normalised to the same
eye-corner scale by the model, so the displacement carries over as it is): a wide mouth stays a
wide mouth, the driver's shape never replaces the source's. The source's fit is deformed by it as
an edit is (paper Eq. 5, :func:`facesculpt.geometry.merge_deformation`) and composited from the
source frame by the project's :class:`Compositor` (background kept, uncovered regions inpainted).

With ``pose`` the head also turns as the driver's turns away from its own neutral pose (the mean
rotation of the calibration frames), about the source head's centre; translation is not carried.

The mouth: where the rendered inner lips open wider than the source frame's own mouth, the gap is
painted as a dark interior with a soft teeth band under the upper lip
(:mod:`facesculpt.nodes.renderer.mouth_interior`), but only when the source's mouth is closed
(inner lips under :data:`~facesculpt.nodes.renderer.mouth_interior.CLOSED_MOUTH_PX` apart): a source that
shows its own mouth open (its
teeth) keeps them, stretched by the warp as the mouth opens further. Dense (``facemesh``) models only for the mouth polygon; a sparse model gets its iBUG
inner-lip points 61–68.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesculpt.geometry import merge_deformation
from facesculpt.geometry.projection import project
from facesculpt.nodes.camera.intrinsics import FOV_DEG
from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.nodes.landmarks.detector import FACE_OPTIONS
from facesculpt.nodes.renderer.mouth_interior import (
    CLOSED_MOUTH_PX,
    INNER_LIP_FACEMESH,
    opening_px,
    paint_mouth_interior,
)

#: A source mouth whose inner lips are at least this far apart (px, :func:`opening_px`) shows its own
#: interior, which the warp then stretches; a closer one gets the painted interior.


def mean_rotation(rotations: list[np.ndarray]) -> np.ndarray:
    """(3, 3) the chordal mean of rotations (their sum projected onto SO(3))."""
    U, _, Vt = np.linalg.svd(np.sum(rotations, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def inner_lip_ids(model) -> np.ndarray:
    """(N,) int vertices of the inner lip line, upper lip first: the face mesh's own loop, or a
    sparse model's iBUG 61–65 then 66–68."""
    if model.dense:
        return np.asarray(INNER_LIP_FACEMESH, np.int64)
    names = {str(n): int(i) for n, i in zip(model.landmark_names, np.asarray(model.landmark_vertices).ravel())}
    return np.array([names[str(k)] for k in (61, 62, 63, 64, 65, 66, 67, 68)], np.int64)


@dataclass
class SourceFace:
    """The source: image (H, W, 3) uint8 BGR; fit (:class:`FitResult`) made on it; neutral (V, 3)
    model space mm (the fitter's, learned from this frame)."""

    image: np.ndarray
    fit: object
    neutral: np.ndarray


def fit_source(image: np.ndarray, model="facemesh", fov_deg: float = FOV_DEG, threads: int = FACE_OPTIONS.threads) -> SourceFace:
    """Fit the source frame (H, W, 3) uint8 BGR; its neutral is learned from this frame alone.
    ValueError when no face is found."""
    from facesculpt.app.pipeline import Pipeline

    with Pipeline(model, threads=threads, fov_deg=fov_deg, fit=FitterConfig(neutral_frames=1)) as pipe:
        fit = None
        for attempt in range(2):  # the second pass tracks from the first one's points
            fit = pipe.fit_frame(image, float(attempt)) or fit
        if fit is None:
            raise ValueError("no face was found in the source image")
        return SourceFace(image, fit, np.array(pipe.neutral, np.float32))


class Reenactor:
    """Renders the source with a driving fit's expression (and pose). source: :class:`SourceFace`;
    model: the :class:`MorphableModel` both were fitted with; driver_neutral (V, 3) model space, mm;
    driver_rotation (3, 3): the driver's neutral head rotation (None: pose not carried);
    mouth: paint the mouth interior. Call :meth:`render` per driving fit; :meth:`close` frees GL."""

    def __init__(self, source: SourceFace, model, driver_neutral: np.ndarray,
                 driver_rotation: np.ndarray | None = None, mouth: bool = True, **compositor_options):
        from facesculpt.nodes.renderer import Compositor

        self.source, self.model = source, model
        self.driver_neutral = np.asarray(driver_neutral, np.float64)
        self.driver_rotation = driver_rotation
        self.mouth = mouth
        h, w = source.image.shape[:2]
        self.compositor = Compositor(w, h, **compositor_options)
        self.lips = inner_lip_ids(model)
        self.source_opening = opening_px(source.fit.projected[self.lips])
        self.displacement = np.zeros_like(self.driver_neutral, np.float32)

    def deformed(self, driver_fit) -> np.ndarray:
        """(V, 3) the source's fitted mesh in its camera space deformed by ``driver_fit``'s
        expression displacement (and turned by its pose when carried); a missing fit (None)
        keeps the last displacement."""
        src = self.source.fit
        if driver_fit is not None:
            self.displacement = (np.asarray(driver_fit.model_vertices, np.float64)
                                 - self.driver_neutral).astype(np.float32)
        out = merge_deformation(src.vertices, src.R, src.scale, self.displacement).astype(np.float64)
        if self.driver_rotation is not None and driver_fit is not None:
            turn = np.asarray(driver_fit.R, np.float64) @ self.driver_rotation.T
            centre = np.asarray(src.vertices, np.float64).mean(0)
            out = (out - centre) @ turn.T + centre
        return out.astype(np.float32)

    def render(self, driver_fit) -> np.ndarray:
        """(H, W, 3) uint8 BGR: the source frame with its face animated by ``driver_fit``."""
        src = self.source.fit
        deformed = self.deformed(driver_fit)
        out = self.compositor.render(self.source.image, src.vertices, src.projected, self.model.triangles, deformed)
        if self.mouth and self.source_opening < CLOSED_MOUTH_PX:
            lips = deformed[self.lips].astype(np.float64)
            poly = project(lips, src.K) if src.K is not None else lips[:, :2]
            out = paint_mouth_interior(out, poly, self.source_opening)
        return out

    def close(self) -> None:
        self.compositor.release()
