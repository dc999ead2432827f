"""Camera pose from 2D-3D and 3D-3D correspondences: scaled orthographic, perspective (intrinsics K),
and weighted similarity Procrustes.

Conventions. Model space: x toward the subject's left, y up, z out of the face (mm). Camera space is
OpenCV's: x right, y down, z forward (away from the camera); image pixels: x right, y down. A face
looking into the camera therefore has R = diag(1, -1, -1).

* Scaled orthographic: ``camera = s · R · X + (tx, ty, 0)``; pixels are its first two coordinates
  (``s`` in px per model unit, the depth z in the same pixel scale).
* Perspective: ``camera = R · X + t`` (model units, mm), pixels ``= π(K · camera)``.

Projecting points: :mod:`facesculpt.geometry.projection`.
"""

from __future__ import annotations

import numpy as np

from facesculpt.geometry import similarity
from facesculpt.geometry.head_angles import FRONTAL, euler_from_rotation, rotation_from_euler  # noqa: F401 (this module's API)
from facesculpt.geometry.projection import project


class PoseError(ValueError):
    """The correspondences do not determine a pose (too few, collinear, or not finite)."""


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    v = np.asarray(v, np.float64)
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [np.stack([z, -v[..., 2], v[..., 1]], -1),
         np.stack([v[..., 2], z, -v[..., 0]], -1),
         np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def rodrigues(omega: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) (radians) -> rotation matrix (3, 3)."""
    x, y, z = (float(v) for v in omega)
    theta = (x * x + y * y + z * z) ** 0.5
    if theta < 1e-12:
        return np.array([[1.0, -z, y], [z, 1.0, -x], [-y, x, 1.0]])
    kx, ky, kz = x / theta, y / theta, z / theta
    c, sn = np.cos(theta), np.sin(theta)
    v = 1.0 - c
    return np.array([
        [c + kx * kx * v, kx * ky * v - kz * sn, kx * kz * v + ky * sn],
        [ky * kx * v + kz * sn, c + ky * ky * v, ky * kz * v - kx * sn],
        [kz * kx * v - ky * sn, kz * ky * v + kx * sn, c + kz * kz * v],
    ])


def rotation_log(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) -> rotation vector (3,) (radians)."""
    R = np.asarray(R, np.float64)
    cos = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    theta = np.arccos(cos)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if theta < 1e-6:
        return w / 2
    if np.pi - theta < 1e-4:
        # Near 180°: axis from the symmetric part.
        M = (R + np.eye(3)) / 2
        axis = M[np.argmax(np.diag(M))]
        axis = axis / np.linalg.norm(axis)
        if w @ axis < 0:
            axis = -axis
        return axis * theta
    return w * theta / (2 * np.sin(theta))


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation matrix closest (Frobenius) to a 3×3 matrix."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _check(points3d: np.ndarray, points2d: np.ndarray, weights: np.ndarray | None, need: int):
    X = np.asarray(points3d, np.float64)
    x = np.asarray(points2d, np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or x.ndim != 2 or x.shape[1] != 2 or len(X) != len(x):
        raise PoseError(f"need (N, 3) model points and (N, 2) image points, got {X.shape} and {x.shape}")
    if len(X) < need:
        raise PoseError(f"a pose needs at least {need} correspondences, got {len(X)}")
    if not (np.isfinite(X).all() and np.isfinite(x).all()):
        raise PoseError("correspondences contain NaN or infinite values")
    w = np.ones(len(X)) if weights is None else np.asarray(weights, np.float64).reshape(-1)
    if w.shape != (len(X),) or (w < 0).any() or w.sum() <= 0:
        raise PoseError("weights must be (N,) non-negative with a positive sum")
    return X, x, w


def _spread_check(Xc: np.ndarray, xc: np.ndarray, w: np.ndarray) -> None:
    s3 = np.linalg.svd(Xc * np.sqrt(w)[:, None], compute_uv=False)
    s2 = np.linalg.svd(xc * np.sqrt(w)[:, None], compute_uv=False)
    if s3[0] <= 0 or s3[1] < 1e-6 * s3[0]:
        raise PoseError("model points are collinear (or coincide): the pose is undetermined")
    if s2[0] <= 0 or s2[1] < 1e-3 * s2[0]:
        raise PoseError("image points are collinear (or coincide): the pose is undetermined")


def scaled_orthographic(
    points3d: np.ndarray,
    points2d: np.ndarray,
    weights: np.ndarray | None = None,
    init: tuple[np.ndarray, float] | None = None,
    iterations: int = 8,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Scaled orthographic pose minimising Σ w ‖s·R[:2]·X + t − x‖².

    points3d (N, 3) model units; points2d (N, 2) pixels; weights (N,); init (R, s) to start from
    (e.g. the previous frame's). Returns R (3, 3) rotation, t (3,) = (tx, ty, 0) pixels, s px/unit.
    Starts from the affine least-squares camera made orthogonal (when no init; collinear points are
    refused then), then Gauss-Newton."""
    X, x, w = _check(points3d, points2d, weights, 4)
    W = w / w.sum()
    Xm = W @ X
    xm = W @ x
    Xc = X - Xm
    xc = x - xm
    sw = np.sqrt(W)[:, None]
    if init is None:
        _spread_check(Xc, xc, w)
        # Affine camera by weighted least squares, then the nearest scaled rotation.
        M, *_ = np.linalg.lstsq(Xc * sw, xc * sw, rcond=None)  # (3, 2)
        A = M.T
        U, S, Vt = np.linalg.svd(A, full_matrices=False)
        r12 = U @ Vt
        s = float(S.mean())
        R = np.vstack([r12, np.cross(r12[0], r12[1])])
        R = nearest_rotation(R)
    else:
        R, s = np.asarray(init[0], np.float64), float(init[1])
        if not (np.isfinite(R).all() and np.isfinite(s) and s > 0):
            return scaled_orthographic(X, x, w, None, iterations)
    sw1 = sw[:, 0]
    J = np.empty((2, len(X), 4))
    for _ in range(iterations):
        RX = Xc @ R.T  # (N, 3)
        px, py = s * RX[:, 0], s * RX[:, 1]
        sz = s * RX[:, 2]
        r = np.concatenate([(px - xc[:, 0]) * sw1, (py - xc[:, 1]) * sw1])
        # d(R X)/dω = -[R X]x for the left perturbation exp([ω]) R; last column d/d(log s).
        J[0, :, 0] = 0.0
        J[0, :, 1] = sz
        J[0, :, 2] = -py
        J[0, :, 3] = px
        J[1, :, 0] = -sz
        J[1, :, 1] = 0.0
        J[1, :, 2] = px
        J[1, :, 3] = py
        Jw = (J * sw1[None, :, None]).reshape(-1, 4)
        H = Jw.T @ Jw
        H += 1e-9 * np.trace(H) * np.eye(4)
        delta = -np.linalg.solve(H, Jw.T @ r)
        R = rodrigues(delta[:3]) @ R
        s = s * float(np.exp(delta[3]))
        if np.abs(delta).max() < 1e-7:
            break
    t = np.zeros(3)
    t[:2] = xm - s * (R @ Xm)[:2]
    return R, t, s


def projection_jacobian(points_cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N, 2, 3): d pixel / d camera point, for the pinhole camera K (skew ignored)."""
    p = np.asarray(points_cam, np.float64)
    z = p[:, 2]
    fx, fy = K[0, 0], K[1, 1]
    J = np.zeros((len(p), 2, 3))
    J[:, 0, 0] = fx / z
    J[:, 0, 2] = -fx * p[:, 0] / z**2
    J[:, 1, 1] = fy / z
    J[:, 1, 2] = -fy * p[:, 1] / z**2
    return J


def check_intrinsics(K: np.ndarray) -> np.ndarray:
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0 or abs(K[2, 2] - 1) > 1e-6:
        raise PoseError(f"K must be a 3x3 pinhole intrinsics matrix with positive focal lengths, got {K.tolist()}")
    return K


def perspective(
    points3d: np.ndarray,
    points2d: np.ndarray,
    K: np.ndarray,
    weights: np.ndarray | None = None,
    init: tuple[np.ndarray, np.ndarray] | None = None,
    iterations: int = 8,
    rotation_prior: tuple[np.ndarray, float | tuple[float, float, float]] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Perspective pose (R, t) minimising Σ w ‖π(K (R X + t)) − x‖² / Σ w (Gauss-Newton on the pixel
    error), plus ‖λ ∘ log(R_pᵀ R)‖² with ``rotation_prior`` (R_p (3, 3), λ px per radian: a
    number, or (3,) about the model's x, y, z axes, e.g. only the pitch's).

    points3d (N, 3) model units (mm); points2d (N, 2) pixels; K (3, 3); init (R, t) to start from.
    Without init, starts from the scaled orthographic pose about the principal point (depth f / s).
    Returns R (3, 3), t (3,) in model units."""
    X, x, w = _check(points3d, points2d, weights, 4)
    K = check_intrinsics(K)
    sw = np.sqrt(w / w.sum())
    if init is None:
        R, t2, s = scaled_orthographic(X, x, w)
        f = 0.5 * (K[0, 0] + K[1, 1])
        tz = f / s
        # s R X + t2 ≈ f (R X + t)/tz + c  ⇒  t_xy = (t2 − c) tz / f
        t = np.array([(t2[0] - K[0, 2]) * tz / K[0, 0], (t2[1] - K[1, 2]) * tz / K[1, 1], tz])
    else:
        R, t = np.asarray(init[0], np.float64), np.asarray(init[1], np.float64).copy()
    for _ in range(iterations):
        RX = X @ R.T
        C = RX + t
        if (C[:, 2] <= 1e-6).any():
            raise PoseError("points fall behind the camera: no perspective pose from these correspondences")
        r = (project(C, K) - x) * sw[:, None]
        Jp = projection_jacobian(C, K)  # (N, 2, 3)
        # Row j of the projection Jacobian times -[R X]x is (R X) x j.
        a = RX[:, None, :]
        Jw = np.stack([a[..., 1] * Jp[..., 2] - a[..., 2] * Jp[..., 1],
                       a[..., 2] * Jp[..., 0] - a[..., 0] * Jp[..., 2],
                       a[..., 0] * Jp[..., 1] - a[..., 1] * Jp[..., 0]], axis=-1)
        J = np.concatenate([Jw, Jp], axis=2) * sw[:, None, None]
        J, r = J.reshape(-1, 6), r.reshape(-1)
        if rotation_prior is not None:
            J, r = _with_rotation_prior(J, r, R, *rotation_prior)
        H = J.T @ J
        H += 1e-9 * np.trace(H) * np.eye(6)
        delta = -np.linalg.solve(H, J.T @ r)
        R = rodrigues(delta[:3]) @ R
        t = t + delta[3:]
        if np.abs(delta[:3]).max() < 1e-7 and np.abs(delta[3:]).max() < 1e-5:
            break
    return R, t


def _with_rotation_prior(J: np.ndarray, r: np.ndarray, R: np.ndarray, R_prior: np.ndarray, weights):
    """The Gauss-Newton rows (J (M, 6), r (M,)) with three more: the rotation vector of R_priorᵀ R
    (about the model's own x, y, z axes) times ``weights`` (a number or (3,) px per radian),
    linearised for the update R ← exp([δ]x) R (δ in camera axes: the rotation vector moves by
    Rᵀ δ, to first order)."""
    w = np.broadcast_to(np.asarray(weights, np.float64), (3,))
    e = rotation_log(np.asarray(R_prior, np.float64).T @ R)
    rows = np.zeros((3, 6))
    rows[:, :3] = w[:, None] * R.T
    return np.vstack([J, rows]), np.r_[r, w * e]


def similarity_procrustes(
    source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None, allow_scale: bool = True
) -> tuple[float, np.ndarray, np.ndarray]:
    """:func:`facesculpt.geometry.similarity.similarity_procrustes` (``target ≈ s · R · source + t``;
    returns s, R (3, 3), t (3,)) raising :class:`PoseError` for point sets it cannot align."""
    try:
        return similarity.similarity_procrustes(source, target, weights, allow_scale)
    except ValueError as exc:
        raise PoseError(str(exc)) from None
