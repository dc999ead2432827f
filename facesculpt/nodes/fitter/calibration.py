"""Where the landmark network's points lie on a model: a calibration learned from renders at known
pose (issue 46).

The network's point for a named landmark is not the model vertex it is mapped to: each lies a
few millimetres off it, partly in depth, which shows in the image as an offset that grows with
the head's turn. Given sequences whose true head, pose and camera are known, each landmark's
model-space point is the one whose projections best match the network's points over the frames
(:func:`triangulate`); its offset from the true head's landmark vertex, averaged over sequences of
different people, is the calibration's offset, and the spread of the network's points about it
(px) gives the landmark's weight, 1/sigma², scaled to a mean of 1 (:func:`learn_calibration`).

A calibration is data of the model: :func:`calibrated` puts it into a :class:`.model.MorphableModel`
(``landmark_offsets``, ``landmark_weights``, ``calibration``: its provenance), which the sparse
fitter then uses; :func:`save_calibration` / :func:`load_calibration` keep it in a ``.npz`` file,
:func:`calibration_file` is where ``load_model`` looks for one of a model that is built on the fly.

Poses: ``R`` (F, 3, 3) model-to-camera rotations and ``c`` (F, 3) mm such that a model-space
point X (mm) is at ``R[i] @ X + c[i]`` in camera mm (OpenCV axes); ``K`` (3, 3) intrinsics;
pixels in the project's convention (pixel centres at integer coordinates).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from facesculpt.geometry.head_angles import euler_from_rotation
from facesculpt.geometry.similarity import similarity_procrustes
from facesculpt.nodes.fitter.model import ModelFormatError, MorphableModel

CALIBRATION_FORMAT = "facesculpt-landmark-calibration"
#: Bounds on a landmark's weight (relative to a mean of 1): one noisy point must not vanish, one
#: steady point must not carry the fit alone.
WEIGHT_RANGE = (0.25, 4.0)


def project_model(K: np.ndarray, R: np.ndarray, c: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(F, P, 2) px of model-space points X (P, 3) mm (or (F, P, 3), one set per frame)."""
    X = np.broadcast_to(np.asarray(X, np.float64), (len(R),) + np.shape(X)[-2:])
    C = np.einsum("fij,fpj->fpi", R, X) + c[:, None, :]
    uv = C[..., :2] / C[..., 2:3] * np.array([K[0, 0], K[1, 1]]) + K[:2, 2]
    return uv - 0.5


def triangulate(K: np.ndarray, R: np.ndarray, c: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(P, 3) model-space points (mm) whose projections under the poses best match ``observed``
    (F, P, 2) px (rows with NaN skipped; NaN for a point seen in fewer than 2 frames): linear least
    squares, each equation scaled to pixels at its frame's depth."""
    f = np.array([K[0, 0], K[1, 1]])
    out = np.full((observed.shape[1], 3), np.nan)
    for p in range(observed.shape[1]):
        ok = np.isfinite(observed[:, p]).all(1)
        if ok.sum() < 2:
            continue
        u = observed[ok, p] + 0.5 - K[:2, 2]                   # (n, 2) px from the principal point
        Rk, ck = R[ok], c[ok]
        z = ck[:, 2:3]
        # u C_z - f C_xy = 0 with C = R X + c: rows (n, 2, 3), right-hand sides (n, 2)
        rows = u[:, :, None] * Rk[:, 2:3, :] - f[None, :, None] * Rk[:, :2, :]
        rhs = -(u * ck[:, 2:3] - f * ck[:, :2])
        out[p] = np.linalg.lstsq((rows / z[:, :, None]).reshape(-1, 3), (rhs / z).reshape(-1), rcond=None)[0]
    return out


def network_rotation(points3d: np.ndarray, R_true: np.ndarray, depth_scale: float = 1.0,
                     rows: np.ndarray | None = None) -> dict:
    """The head's rotation as the network's own 3D points (F, N, 3) (x, y px, z relative depth px,
    camera axes) give it against the truth ``R_true`` (F, 3, 3): each frame's similarity
    Procrustes from the frame nearest frontal, composed with that frame's true rotation. Returns
    per-frame ``yaw``, ``pitch`` (network, degrees), the true ones, and the least-squares
    ``yaw_slope``, ``pitch_slope`` (network angle per true angle, about the reference frame).
    ``depth_scale`` multiplies the network's depths first; ``rows`` picks the points used."""
    P = np.asarray(points3d, np.float64)
    if rows is not None:
        P = P[:, rows]
    P = P * np.array([1.0, 1.0, depth_scale])
    true = np.array([euler_from_rotation(R)[:2] for R in R_true])
    ok = np.isfinite(P).all(axis=(1, 2))
    ref = int(np.argmin(np.where(ok, np.abs(true).sum(1), np.inf)))
    net = np.full_like(true, np.nan)
    for i in np.flatnonzero(ok):
        _, Rr, _ = similarity_procrustes(P[ref], P[i])
        net[i] = euler_from_rotation(Rr @ R_true[ref])[:2]
    d_true, d_net = true[ok] - true[ref], net[ok] - true[ref]
    slopes = [float(d_true[:, k] @ d_net[:, k] / (d_true[:, k] @ d_true[:, k])) for k in range(2)]
    return {"yaw": net[:, 0], "pitch": net[:, 1], "true_yaw": true[:, 0], "true_pitch": true[:, 1],
            "yaw_slope": slopes[0], "pitch_slope": slopes[1], "reference": ref}


def view_direction(R: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(F, 3) unit vectors, model space: from the model's origin toward the camera, at the poses
    R (F, 3, 3), c (F, 3) (a perspective camera at the origin of camera space)."""
    d = -np.einsum("fji,fj->fi", R, c)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def triangulate_posed(K: np.ndarray, R: np.ndarray, c: np.ndarray, observed: np.ndarray,
                      ridge_px: float = 1.0) -> np.ndarray:
    """(P, 3, 3) per point its model-space position (row 0, mm) and how it moves with the view
    (rows 1, 2: mm per unit of the view direction's x and y, :func:`view_direction`): the point
    ``X + d_x A + d_y B`` whose projections best match ``observed`` (F, P, 2) px in linear least
    squares, each equation scaled to pixels at its frame's depth, A and B pulled toward 0 with
    ``ridge_px`` px per mm. NaN for a point seen in fewer than 4 frames."""
    f = np.array([K[0, 0], K[1, 1]])
    d = view_direction(R, c)
    out = np.full((observed.shape[1], 3, 3), np.nan)
    ridge = np.hstack([np.zeros((6, 3)), ridge_px * np.eye(6)])
    for p in range(observed.shape[1]):
        ok = np.isfinite(observed[:, p]).all(1)
        if ok.sum() < 4:
            continue
        u = observed[ok, p] + 0.5 - K[:2, 2]
        Rk, ck, dk = R[ok], c[ok], d[ok]
        z = ck[:, 2:3]
        rows = (u[:, :, None] * Rk[:, 2:3, :] - f[None, :, None] * Rk[:, :2, :]) / z[:, :, None]   # (n, 2, 3)
        design = np.concatenate([rows, dk[:, 0, None, None] * rows, dk[:, 1, None, None] * rows], axis=2)
        rhs = -(u * ck[:, 2:3] - f * ck[:, :2]) / z
        A = np.vstack([design.reshape(-1, 9), ridge])
        b = np.concatenate([rhs.reshape(-1), np.zeros(6)])
        out[p] = np.linalg.lstsq(A, b, rcond=None)[0].reshape(3, 3)
    return out


def learn_calibration(sequences: list[dict]) -> dict:
    """The calibration of L landmarks from sequences, each a dict with ``K``, ``R``, ``c`` (the
    poses, as the module docstring says), ``observed`` (F, L, 2) px (the network's points, NaN
    where missing) and ``vertices`` (L, 3) model mm (the true head's landmark vertices). Returns
    ``offsets`` (L, 3) mm (mean over the sequences of the triangulated point less the vertex),
    ``sigma`` (L,) px (RMS distance of the network's points from the offset point's projection,
    over all frames) and ``weights`` (L,) (1/sigma², mean 1, within :data:`WEIGHT_RANGE`)."""
    if not sequences:
        raise ValueError("a calibration needs at least one sequence")
    per = [triangulate(s["K"], s["R"], s["c"], s["observed"]) - s["vertices"] for s in sequences]
    offsets = np.nanmean(np.array(per), axis=0)
    if not np.isfinite(offsets).all():
        raise ValueError("a landmark was seen in fewer than 2 frames of every sequence")
    sq = [np.linalg.norm(s["observed"] - project_model(s["K"], s["R"], s["c"], s["vertices"] + offsets), axis=2) ** 2
          for s in sequences]
    sigma = np.sqrt(np.nanmean(np.concatenate(sq), axis=0))
    weights = 1.0 / np.maximum(sigma, 1e-3) ** 2
    weights = np.clip(weights / weights.mean(), *WEIGHT_RANGE)
    return {"offsets": offsets, "sigma": sigma, "weights": weights / weights.mean()}


def uncalibrated(model: MorphableModel) -> MorphableModel:
    """A copy of ``model`` without a landmark calibration (each landmark at its vertex, weight 1)."""
    return replace(model, landmark_offsets=np.zeros((0, 3), np.float32), landmark_weights=np.zeros(0, np.float32),
                   network_rotation_gain=np.zeros(0, np.float32), calibration="")


def fixed_landmarks(model: MorphableModel) -> list[str]:
    """The model's iBUG landmarks (1-based names, "1".."68") with a fixed vertex (not on the
    outline, whose correspondence moves with the pose): the landmarks a calibration learns."""
    outline = set(model.outline_landmarks_right) | set(model.outline_landmarks_left)
    return [n for n in model.landmark_names if n.isdigit() and 1 <= int(n) <= 68 and n not in outline]


def calibrated(model: MorphableModel, names: list[str], offsets: np.ndarray, weights: np.ndarray,
               provenance: str, rotation_gain=()) -> MorphableModel:
    """A copy of ``model`` with the calibration of the landmarks ``names`` (offsets (L, 3) mm,
    weights (L,)) and the network's rotation gain (3,) (or none: ``()``); its other landmarks keep
    their vertex and weight 1. ValueError for a name the model does not have."""
    index = {n: i for i, n in enumerate(model.landmark_names)}
    missing = [n for n in names if n not in index]
    if missing:
        raise ValueError(f"model {model.model_id} has no landmark named {', '.join(missing)}")
    L = len(model.landmark_names)
    offs, W = np.zeros((L, 3), np.float32), np.ones(L, np.float32)
    rows = [index[n] for n in names]
    offs[rows], W[rows] = np.asarray(offsets, np.float32), np.asarray(weights, np.float32)
    return replace(model, landmark_offsets=offs, landmark_weights=W, calibration=str(provenance),
                   network_rotation_gain=np.asarray(rotation_gain, np.float32))


def save_calibration(path: str | Path, model_id: str, names: list[str], offsets: np.ndarray, weights: np.ndarray,
                     provenance: str, rotation_gain=()) -> Path:
    """Write a calibration of model ``model_id``'s landmarks ``names`` (and the network's rotation
    gain, :func:`calibrated`) to ``path`` (.npz)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        np.savez(fh, format=np.str_(CALIBRATION_FORMAT), model_id=np.str_(model_id),
                 names=np.asarray(list(names), np.str_), offsets=np.asarray(offsets, np.float32),
                 weights=np.asarray(weights, np.float32), provenance=np.str_(provenance),
                 rotation_gain=np.asarray(rotation_gain, np.float32))
    return path


def load_calibration(path: str | Path, model: MorphableModel) -> MorphableModel:
    """``model`` with the calibration in ``path`` (written by :func:`save_calibration` for the same
    model id). ModelFormatError when the file is not one, or is another model's."""
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["format"]) != CALIBRATION_FORMAT:
                raise ModelFormatError(f"{path}: not a landmark calibration")
            if str(data["model_id"]) != model.model_id:
                raise ModelFormatError(f"{path}: a calibration of model {str(data['model_id'])!r}, not {model.model_id!r}")
            names = [str(n) for n in data["names"].tolist()]
            gain = data["rotation_gain"] if "rotation_gain" in data.files else ()
            return calibrated(model, names, data["offsets"], data["weights"], str(data["provenance"]), gain)
    except ModelFormatError:
        raise
    except (OSError, KeyError, ValueError) as exc:
        raise ModelFormatError(f"{path}: not a readable landmark calibration ({exc})") from None


def calibration_file(model_id: str) -> Path:
    """Where the calibration of a model built on the fly (``load_model("sfm")``) is kept: the
    models folder of `facesculpt setup`, ``calibration/<model_id>.npz``."""
    from facesculpt.paths import model_home

    return model_home() / "calibration" / f"{model_id}.npz"


def fitted_landmarks(fit, model: MorphableModel) -> dict[str, np.ndarray]:
    """Landmark id -> (2,) px: where a sparse fit (:class:`.result.FitResult` of ``model``) puts
    each landmark it was fitted to: its correspondence on the fitted mesh, moved by the model's
    calibration offset (turned and scaled with the head) where the model has one."""
    from facesculpt.geometry.projection import project

    verts, weights = fit.correspondences
    points = (np.asarray(fit.vertices, np.float64)[verts] * np.asarray(weights)[..., None]).sum(axis=1)
    if len(model.landmark_offsets):
        offset = dict(zip(model.landmark_names, np.asarray(model.landmark_offsets, np.float64)))
        moved = np.array([offset.get(i, np.zeros(3)) for i in fit.correspondence_ids])
        scale = float(fit.scale) if fit.projection == "orthographic" else 1.0
        points = points + scale * moved @ np.asarray(fit.R, np.float64).T
    px = project(points, fit.K, fit.projection)
    return dict(zip(fit.correspondence_ids, px))
