"""Landmark corrections that follow the head (seed 002's interactive correction).

A person drags a landmark to where it belongs on one frame. The correction is kept in the head's
own frame: the 3D point under the pixel the person chose (at the depth of the fitted surface
there, or of the landmark when the pixel is off the face), taken back through that frame's head
pose. On every later frame it is projected with that frame's head pose, so it moves with the head,
and the fitter uses it with a high weight (``Fitter.fit(..., corrections=...)``).

The head pose must not come from a fit the correction itself pulled: a pulled landmark tilts and
shifts the fitted pose, the target moves with it, and the next fit is pulled further (on a still
frame the chin ran on past where it was put; on a turning head the target wandered by many times
the inter-ocular distance). So when the frame's detected points are given, the head's pose is
that of a rigid reference placed on them: the nose and eyes (iBUG 28-48, which expression
moves least) of the fit the first correction was made on, in model coordinates, posed
on those points of each frame's detection, which no correction touches. Without detected points,
the fit's own pose serves. Landmarks are named by their iBUG-68 number (1..68) for both built-in
models: the face mesh fits its own vertex numbers, which :func:`fit_id` gives.
"""

from __future__ import annotations

import numpy as np

from facesculpt.geometry.ibug68 import IBUG68_FROM_MESH, to_ibug68
from facesculpt.geometry.projection import pixel_ray
from facesculpt.geometry.ray_mesh import ray_mesh_hit
from facesculpt.nodes.fitter import pose

#: iBUG numbers of the head's rigid reference: nose and eyes (the brows, mouth and jaw, which
#: expression and speech move most, are left out).
REFERENCE_IBUG = np.arange(28, 49)


def fit_id(ibug: int | str, dense: bool) -> str:
    """The id the fitter knows iBUG point ``ibug`` (1..68) by: the face-mesh vertex number for the
    dense model, the iBUG number itself for a sparse one; ValueError outside 1..68."""
    try:
        k = int(ibug)
    except (TypeError, ValueError):
        k = 0
    if not 1 <= k <= 68:
        raise ValueError(f"a landmark to correct is an iBUG number from 1 to 68, got {ibug!r}")
    return str(int(IBUG68_FROM_MESH[k - 1])) if dense else str(k)


def ibug_number(landmark_id: str, dense: bool) -> int:
    """The iBUG number (1..68) of fit id ``landmark_id`` (the inverse of :func:`fit_id`); 0 when it
    is none of the 68."""
    if dense:
        hit = np.flatnonzero(IBUG68_FROM_MESH == int(landmark_id)) if str(landmark_id).isdigit() else []
        return int(hit[0]) + 1 if len(hit) else 0
    return int(landmark_id) if str(landmark_id).isdigit() and 1 <= int(landmark_id) <= 68 else 0


def ibug68_points(fit, dense: bool) -> np.ndarray:
    """(68, 2) float32 pixels: the fit's iBUG-68 points in iBUG order, as the fit placed them (the
    dense model's mapped vertices; a sparse fit's landmark correspondences, outline ones included),
    NaN where the fit had none (e.g. the SFM's inner mouth corners)."""
    if dense:
        return np.asarray(fit.projected, np.float32)[IBUG68_FROM_MESH]
    out = np.full((68, 2), np.nan, np.float32)
    if fit.correspondences is None:
        return out
    verts, weights = fit.correspondences
    points = (np.asarray(fit.projected, np.float64)[np.asarray(verts, int)] * np.asarray(weights)[..., None]).sum(1)
    for name, xy in zip(getattr(fit, "correspondence_ids", []) or [], points):
        k = ibug_number(name, False)
        if k:
            out[k - 1] = xy
    return out


def _camera_point(fit, xy: np.ndarray, depth: float) -> np.ndarray:
    """The camera-space point under pixel ``xy`` at ``depth`` (perspective) or the fit's plane."""
    if fit.K is None or fit.projection != "perspective":
        return np.array([xy[0], xy[1], depth])
    K = np.asarray(fit.K, np.float64)
    return np.array([(xy[0] - K[0, 2]) * depth / K[0, 0], (xy[1] - K[1, 2]) * depth / K[1, 1], depth])


def _project(fit, X: np.ndarray) -> np.ndarray:
    if fit.K is None or fit.projection != "perspective":
        return X[:2].copy()
    K = np.asarray(fit.K, np.float64)
    return np.array([K[0, 0] * X[0] / X[2] + K[0, 2], K[1, 1] * X[1] / X[2] + K[1, 2]])


def _reference_points(fit, model) -> tuple[np.ndarray, np.ndarray]:
    """(iBUG indices (M,) 0-based, their points (M, 3) in model coordinates, mm): the fit's
    :data:`REFERENCE_IBUG` landmarks on its fitted shape (``fit.model_vertices``)."""
    shape = np.asarray(fit.model_vertices, np.float64)
    if model.dense:
        idx = REFERENCE_IBUG - 1
        return idx, shape[IBUG68_FROM_MESH[idx]]
    names = {str(n): int(i) for n, i in zip(model.landmark_names, model.landmark_vertices)}
    idx = np.array([k - 1 for k in REFERENCE_IBUG if str(k) in names], int)
    return idx, shape[[names[str(k + 1)] for k in idx]]


def _detected68(points) -> np.ndarray:
    """(68, 2) iBUG-68 pixels of one face's detected points: (468, 2|3) face-mesh or (68, 2|3) iBUG."""
    points = np.asarray(points, np.float64)
    return to_ibug68(points).astype(np.float64) if points.shape[0] != 68 else points[:, :2]


class LandmarkCorrections:
    """The corrections of one face: :meth:`set` on a frame's fit, :meth:`targets` for the next
    (both given the frame's detected points, so the head's pose comes from them; see the module)."""

    def __init__(self):
        self.anchors: dict[str, np.ndarray] = {}  # fit id -> (3,) point in the head's frame, model mm
        self.reference: tuple[np.ndarray, np.ndarray] | None = None  # (iBUG indices, (M, 3) model mm)
        self.pose: tuple | None = None  # (R, t, s) of the reference on the last detected points

    def __len__(self) -> int:
        return len(self.anchors)

    def clear(self) -> None:
        self.anchors.clear()
        self.reference = self.pose = None

    def ibug(self, dense: bool) -> list[int]:
        """The iBUG numbers (1..68) of the corrected landmarks, ascending."""
        return sorted(k for k in (ibug_number(name, dense) for name in self.anchors) if k)

    def head_pose(self, fit, points=None) -> tuple[np.ndarray, np.ndarray, float]:
        """(R, t, s) of the head in the frame of ``points`` (one face's detected points, (468, 2|3)
        or (68, 2|3) px): the reference posed on them, warm-started from the last frame. Without a
        reference, the fit's own pose; without points (or with too few of the reference's seen),
        the reference's last pose (the fit's before there is one)."""
        own = (np.asarray(fit.R, np.float64), np.asarray(fit.t, np.float64), float(fit.scale))
        if self.reference is None or points is None:
            return self.pose or own
        idx, X = self.reference
        x = _detected68(points)[idx]
        ok = np.isfinite(x).all(axis=1)
        R0, t0, s0 = self.pose or own
        try:
            if fit.K is None or fit.projection != "perspective":
                R, t, s = pose.scaled_orthographic(X[ok], x[ok], None, (R0, s0))
            else:
                (R, t), s = pose.perspective(X[ok], x[ok], fit.K, None, (R0, t0)), 1.0
        except (pose.PoseError, np.linalg.LinAlgError):
            return self.pose or own
        self.pose = (R, np.asarray(t, np.float64), float(s))
        return self.pose

    def set(self, landmark_id: str, xy, fit, model, points=None) -> None:
        """Put landmark ``landmark_id`` (a fit id, :func:`fit_id`) under pixel ``xy`` (2,) on the
        frame ``fit`` (a FitResult of ``model``) was made on; ``points``: that frame's detected
        points of this face (px), whose nose and eyes then carry the correction (see the module).
        ValueError when the landmark took no part in that fit and the pixel is off the face."""
        xy = np.asarray(xy, np.float64)
        K = fit.K if fit.K is not None else np.eye(3)
        origin, direction = pixel_ray(float(xy[0]), float(xy[1]), K, fit.projection)
        hit = ray_mesh_hit(origin, direction, fit.vertices, model.triangles,
                           two_sided_line=fit.projection == "orthographic")
        if hit is not None:  # on the face: the surface's depth there
            depth = float((origin + hit[1] * direction)[2])
        else:  # off the face: the landmark's own depth
            v, b = self._surface_point(str(landmark_id), fit, model)
            depth = float((np.asarray(fit.vertices, np.float64)[v] * b[:, None]).sum(axis=0)[2])
        if points is not None and self.reference is None:
            self.reference, self.pose = _reference_points(fit, model), None
        R, t, s = self.head_pose(fit, points)
        # In the head's own frame (its pose only, not its shape: a shape the correction itself
        # pulls must not carry the target along with it).
        self.anchors[str(landmark_id)] = R.T @ (_camera_point(fit, xy, depth) - t) / s

    @staticmethod
    def _surface_point(landmark_id: str, fit, model) -> tuple[np.ndarray, np.ndarray]:
        ids = list(getattr(fit, "correspondence_ids", []) or [])
        if landmark_id in ids and fit.correspondences is not None:
            k = ids.index(landmark_id)
            return np.asarray(fit.correspondences[0][k], int), np.asarray(fit.correspondences[1][k], np.float64)
        names = {str(n): int(i) for n, i in zip(model.landmark_names, model.landmark_vertices)}
        if landmark_id not in names:
            raise ValueError(f"landmark {landmark_id} took no part in this frame's fit: it cannot be corrected here")
        return np.full(3, names[landmark_id]), np.array([1.0, 0.0, 0.0])

    def targets(self, fit, points=None) -> dict[str, np.ndarray]:
        """fit id -> (2,) pixels: where each corrected landmark is in the frame of ``points`` (this
        face's detected points there, px; see :meth:`head_pose`); ``fit``: the face's latest fit
        (its camera, and its pose when there are no points)."""
        R, t, s = self.head_pose(fit, points)
        return {name: _project(fit, s * (R @ p) + t) for name, p in self.anchors.items()}
