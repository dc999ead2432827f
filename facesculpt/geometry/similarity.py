"""Similarity transforms between point sets: the weighted Umeyama fit, and a similarity as a
7-vector (rotation vector, translation, log scale), the form model-based coding sends per frame.

Shared by the fitter (pose, neutral learning), the talking-heads room (the live coder) and the
application's `.fsc` coder and decoder.
"""

from __future__ import annotations

import numpy as np


def similarity_procrustes(
    source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None, allow_scale: bool = True
) -> tuple[float, np.ndarray, np.ndarray]:
    """Weighted similarity (Umeyama) aligning ``source`` to ``target``: ``target ≈ s · R · source + t``.

    source, target (N, 3); weights (N,). Returns s, R (3, 3) proper rotation, t (3,). ValueError for
    point sets of different or wrong shape, or a source whose points coincide."""
    A = np.asarray(source, np.float64)
    B = np.asarray(target, np.float64)
    if A.shape != B.shape or A.ndim != 2 or A.shape[1] != 3 or len(A) < 3:
        raise ValueError(f"need two (N>=3, 3) point sets of the same shape, got {A.shape} and {B.shape}")
    w = np.ones(len(A)) if weights is None else np.asarray(weights, np.float64).reshape(-1)
    W = w / w.sum()
    ma, mb = W @ A, W @ B
    Ac, Bc = A - ma, B - mb
    cov = (Bc * W[:, None]).T @ Ac
    U, S, Vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(U @ Vt)) or 1.0
    D = np.diag([1.0, 1.0, d])
    R = U @ D @ Vt
    var_a = float(W @ (Ac**2).sum(1))
    if var_a <= 0:
        raise ValueError("source points coincide: no similarity transform")
    s = float((S * np.diag(D)).sum() / var_a) if allow_scale else 1.0
    t = mb - s * R @ ma
    return s, R, t


def similarity_vector(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(7,) float64 the similarity mapping ``source`` (V, 3) onto ``target`` (V, 3), e.g. a fitted
    shape in model mm onto its camera-space mesh: rotation vector (rad), translation (target units),
    natural log of the scale."""
    import cv2  # here, not at the top: the fitter starts without OpenCV (a respawn's imports)

    s, R, t = similarity_procrustes(source, target)
    rvec, _ = cv2.Rodrigues(np.asarray(R, np.float64))
    return np.concatenate([rvec.ravel(), np.asarray(t, np.float64), [np.log(s)]])


def apply_similarity_vector(vector: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(V, 3) float64 ``points`` (V, 3) under the similarity ``vector`` (7,) of :func:`similarity_vector`."""
    import cv2

    R, _ = cv2.Rodrigues(np.asarray(vector[:3], np.float64))
    return np.exp(vector[6]) * np.asarray(points, np.float64) @ R.T + np.asarray(vector[3:6], np.float64)
