"""What a fit returns (:class:`FitResult`) and how it refuses (:class:`FitError`), for the sparse
and the dense fitter alike."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facesculpt.nodes.fitter import pose


class FitError(ValueError):
    """A fit was refused: bad input (NaN, too few or unknown landmarks, degenerate configuration,
    bad image size or intrinsics) or a bad option. The message says which."""


@dataclass
class FitResult:
    """One frame's fit. Camera space is OpenCV's (x right, y down, z away from the camera).

    vertices (V, 3) float32 camera space: mm under ``"perspective"``, pixel scale under
    ``"orthographic"`` (x, y are then pixels and z depth in px); projected (V, 2) float32 pixels;
    R (3, 3) model-to-camera rotation; t (3,) translation (mm, or px with t[2] = 0); scale: px per
    model mm (orthographic) or 1.0 (perspective); alpha (S,), beta (E,) float32 in standard
    deviations; residual_px: RMS landmark reprojection error of the fit (before smoothing);
    model_vertices (V, 3) float32 the fitted shape in model space (mm); landmarks_used: points
    that took part; correspondences (sparse): the model points (vertex triples (L, 3) and
    barycentric weights (L, 3)) the landmarks were matched to, and correspondence_ids the
    landmark of each (L,); expression (E,) float32 the
    expression parameters (:mod:`.expression`) when the caller computed them; pose_edit the
    pose edit a caller applies to this frame (the in-process pipeline): (its
    :class:`facesculpt.geometry.pose_offset.PoseOffset`, the head's pivot (3,) model mm), None: none;
    landmark_fit: the fit this one was refined from by appearance (its pose not yet smoothed), what
    the landmarks alone say; None when not refined."""

    vertices: np.ndarray
    projected: np.ndarray
    R: np.ndarray
    t: np.ndarray
    scale: float
    alpha: np.ndarray
    beta: np.ndarray
    residual_px: float
    projection: str
    K: np.ndarray | None
    model_vertices: np.ndarray
    landmarks_used: int = 0
    correspondences: tuple[np.ndarray, np.ndarray] = field(default=None, repr=False)
    expression: np.ndarray | None = field(default=None, repr=False)
    correspondence_ids: list[str] = field(default_factory=list, repr=False)
    pose_edit: tuple | None = field(default=None, repr=False)
    landmark_fit: FitResult | None = field(default=None, repr=False)

    @property
    def yaw_pitch_roll(self) -> tuple[float, float, float]:
        """Head yaw, pitch, roll in degrees (:func:`.pose.euler_from_rotation`)."""
        return pose.euler_from_rotation(self.R)
