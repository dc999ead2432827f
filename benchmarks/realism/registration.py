"""Where the landmark network's points lie on the true head (issue 46's diagnosis).

On a synthetic sequence the true head, its pose and its vertices are known. For each network point
(the face mesh's 468, or the 51 inner iBUG points the SFM is fitted to) this module measures:

* its image offset from the model point it is mapped to, regressed over the frames on
  ``[1, sin(yaw), sin(pitch)]`` (:func:`pose_regression`);
* the fixed model-space point that explains its image positions best given the true pose (a linear
  triangulation over the frames, :func:`triangulate`), hence the implied 3D offset from the
  mapped vertex;
* how much of the offset one global parameter explains: the face flattened (or deepened) along
  its own depth axis about its centroid (:func:`flattening`), which is what a head turned less than
  the truth looks like in the image, to first order;
* the network's own 3D points' rotation against the truth (:func:`network_rotation`): their
  Procrustes rotation from a reference frame, as a slope of the network's yaw / pitch on the truth.

Arrays in, arrays out. Poses: ``R`` (F, 3, 3) model-to-camera rotations, ``c`` (F, 3) such that a
model-space point X (mm) is at ``R[i] @ X + c[i]`` in camera mm (OpenCV axes); pixels in the
project's convention (centres at integers, :func:`.raster.project_pixels`).
"""

from __future__ import annotations

import numpy as np

from facesculpt.nodes.fitter.calibration import network_rotation, project_model, triangulate  # noqa: F401 (re-exported)


def poses(scene) -> tuple[np.ndarray, np.ndarray]:
    """(R (F, 3, 3), c (F, 3)) of ``scene``'s frames: camera = R @ X + c for model-space X mm."""
    Rs, cs = [], []
    for i in range(scene.frames):
        origin = scene.to_camera(np.zeros((1, 3)), i)[0]   # to_camera is affine
        E = scene.to_camera(np.eye(3), i)
        Rs.append((E - origin).T)
        cs.append(origin)
    return np.array(Rs), np.array(cs)


def pose_regression(errors: np.ndarray, yaw_deg: np.ndarray, pitch_deg: np.ndarray) -> dict:
    """Each point's image error (F, P, 2) px regressed on [1, sin(yaw), sin(pitch)] over the
    frames (NaN rows skipped): ``coef`` (P, 2, 3) px (constant, per unit sin(yaw), per unit
    sin(pitch)), ``r2`` (P, 2) the share of each coordinate's variance about its mean that the two
    pose terms explain, ``fitted`` (F, P, 2) the regression's prediction."""
    A = np.column_stack([np.ones_like(yaw_deg), np.sin(np.radians(yaw_deg)), np.sin(np.radians(pitch_deg))])
    F, P, _ = errors.shape
    coef, r2, fitted = np.zeros((P, 2, 3)), np.zeros((P, 2)), np.full(errors.shape, np.nan)
    for p in range(P):
        for k in range(2):
            y = errors[:, p, k]
            ok = np.isfinite(y)
            if ok.sum() < 4:
                continue
            b, *_ = np.linalg.lstsq(A[ok], y[ok], rcond=None)
            coef[p, k] = b
            fitted[:, p, k] = A @ b
            var = np.var(y[ok])
            r2[p, k] = 1.0 - np.mean((y[ok] - fitted[ok, p, k]) ** 2) / var if var > 0 else 0.0
    return {"coef": coef, "r2": r2, "fitted": fitted}


def flattening(K: np.ndarray, R: np.ndarray, c: np.ndarray, observed: np.ndarray, X: np.ndarray,
               scales: np.ndarray | None = None) -> tuple[float, float]:
    """The one depth scale k of the points X (P, 3) model mm about their centroid's depth (model
    z, out of the face) that best explains ``observed`` (F, P, 2) px: (k, RMS px at k). k < 1: the
    network's points turn as a flatter face, i.e. less than the head."""
    scales = np.linspace(0.3, 1.7, 141) if scales is None else scales
    z0 = float(np.mean(X[:, 2]))
    best = (1.0, np.inf)
    for k in scales:
        Y = X.copy()
        Y[:, 2] = z0 + k * (X[:, 2] - z0)
        e = rms(project_model(K, R, c, Y) - observed)
        if e < best[1]:
            best = (float(k), e)
    return best


def rms(errors: np.ndarray) -> float:
    """Root mean square length (px) of the finite rows of ``errors`` (..., 2)."""
    d = np.linalg.norm(np.asarray(errors, np.float64).reshape(-1, 2), axis=1)
    return float(np.sqrt(np.nanmean(d ** 2)))


def best_depth_scale(points3d: np.ndarray, R_true: np.ndarray, rows=None,
                     scales: np.ndarray | None = None) -> tuple[float, dict]:
    """The depth scale of the network's points whose rotation is closest to the truth (mean
    absolute yaw and pitch error over the frames): (scale, :func:`network_rotation` at it)."""
    scales = np.linspace(0.5, 3.0, 51) if scales is None else scales
    best = None
    for s in scales:
        r = network_rotation(points3d, R_true, float(s), rows)
        e = np.nanmean(np.abs(r["yaw"] - r["true_yaw"])) + np.nanmean(np.abs(r["pitch"] - r["true_pitch"]))
        if best is None or e < best[0]:
            best = (e, float(s), r)
    return best[1], best[2]
