"""The camera a fit is made in: image size, intrinsics K and projection, and what the fitters
need from it (model points to camera space and pixels, the projection's Jacobian, the pose from
2D-3D correspondences).

Orthographic (scaled): camera = s · R X + t with t[2] = 0, pixels = camera x, y; s in px per mm.
Perspective: camera = R X + t (mm), pixels through K (:func:`facesculpt.geometry.projection.project`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesculpt.geometry.projection import project
from facesculpt.nodes.fitter import pose
from facesculpt.nodes.fitter.result import FitError


@dataclass(frozen=True)
class FitCamera:
    """image_size (W, H) px; K (3, 3) intrinsics or None; projection "perspective" or "orthographic"."""

    image_size: tuple[int, int]
    K: np.ndarray | None
    projection: str

    @classmethod
    def make(cls, image_size, K: np.ndarray | None, projection: str = "auto") -> FitCamera:
        """Check the image size (positive W, H) and K (:func:`.pose.check_intrinsics`), and
        resolve ``"auto"``: perspective when K is given. Raises :class:`FitError` saying what is wrong."""
        try:
            w, h = (int(v) for v in image_size)
        except (TypeError, ValueError):
            raise FitError(f"image_size must be (W, H), got {image_size!r}") from None
        if w <= 0 or h <= 0:
            raise FitError(f"image_size must be positive, got {w}x{h}")
        if K is not None:
            try:
                K = pose.check_intrinsics(K)
            except pose.PoseError as exc:
                raise FitError(str(exc)) from None
        if projection == "auto":
            projection = "perspective" if K is not None else "orthographic"
        if projection not in ("perspective", "orthographic"):
            raise FitError(f"projection must be 'perspective' or 'orthographic', got {projection!r}")
        if projection == "perspective" and K is None:
            raise FitError("perspective projection needs the intrinsics K")
        return cls((w, h), K, projection)

    @property
    def perspective(self) -> bool:
        return self.projection == "perspective"

    @property
    def focal_px(self) -> float:
        """Mean focal length of K (px): the px-per-mm scale at 1 mm depth."""
        return 0.5 * (self.K[0, 0] + self.K[1, 1])

    def to_camera(self, X: np.ndarray, R, t, s):
        """Model points (N, 3) -> camera points (N, 3), pixels (N, 2). Raises
        :class:`.pose.PoseError` when a point falls behind a perspective camera."""
        if self.projection == "orthographic":
            C = s * (X @ R.T) + t
            return C, C[:, :2].copy()
        C = X @ R.T + t
        if (C[:, 2] <= 1e-6).any():
            raise pose.PoseError("the fitted face falls behind the camera")
        return C, project(C, self.K)

    def linearisation(self, C: np.ndarray, R, s):
        """Jacobians (L, 2, 3) of pixels w.r.t. model points at camera points C (L, 3), and the
        local px-per-mm scale (L,)."""
        if self.projection == "orthographic":
            J = np.broadcast_to(s * R[:2], (len(C), 2, 3))
            return J, np.full(len(C), s)
        Jp = pose.projection_jacobian(C, self.K)
        return Jp @ R, self.focal_px / C[:, 2]

    def estimate_pose(self, X, x, w, init, rotation_prior=None):
        """(R, t, s) placing model points X (N, 3) on pixels x (N, 2) with weights w (N,);
        ``init`` (R, t, s) or None warm-starts it; ``rotation_prior`` (R_p, px per radian) or None
        (:func:`.pose.perspective`; not used by the orthographic camera). s is 1.0 under perspective."""
        if self.projection == "orthographic":
            return pose.scaled_orthographic(X, x, w, None if init is None else (init[0], init[2]))
        R, t = pose.perspective(X, x, self.K, w, None if init is None else (init[0], init[1]),
                                rotation_prior=rotation_prior)
        return R, t, 1.0
