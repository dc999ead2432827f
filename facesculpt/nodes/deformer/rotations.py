"""Per-cell rotation fit of ARAP's local step (Sorkine & Alexa 2007, Sec. 3; libigl's
``fit_rotations``): for each cell's covariance ``S_i`` the proper rotation ``R_i`` maximising
``tr(R_i S_i)``, by LAPACK's batched SVD or by the same SVD in closed form.

Pure functions: (N, 3, 3) float64 in, (N, 3, 3) float64 out.
"""

from __future__ import annotations

import numpy as np

from .errors import DeformerError


def fit_rotations(S: np.ndarray, method: str = "fast") -> np.ndarray:
    """Rotations ``R_i`` maximising ``tr(R_i S_i)`` for covariances ``S_i = sum_j w e e'^T``.

    S: (N, 3, 3) float64. Returns (N, 3, 3) proper rotations ``R = V diag(1, 1, det(V U^T)) U^T``
    where ``S = U diag(s) V^T`` (SVD with the reflection fix of Sorkine & Alexa).
    method: ``"svd"`` - numpy's batched LAPACK SVD; ``"fast"`` - the same SVD computed in
    closed form, vectorised over the batch (eigen-decomposition of ``S^T S``, then ``U`` from
    ``S V``), which avoids LAPACK's per-matrix overhead; the two agree to rounding (tested).
    """
    S = np.asarray(S, dtype=np.float64)
    if method == "svd":
        U, _, Vt = np.linalg.svd(S)
        R = np.einsum("nji,nkj->nik", Vt, U)  # V @ U^T
        flip = np.linalg.det(R) < 0
        if np.any(flip):
            Vf = np.swapaxes(Vt[flip], 1, 2).copy()
            Vf[:, :, 2] *= -1.0
            R[flip] = Vf @ np.swapaxes(U[flip], 1, 2)
        return R
    if method != "fast":
        raise DeformerError(f"unknown rotation method {method!r} (use 'fast' or 'svd')")
    return _rotations_closed_form(S)


# Closed-form batched SVD. Every vector is a tuple of three length-N arrays (structure of
# arrays), so each numpy call does work across the whole batch; LAPACK's batched SVD pays a
# per-matrix overhead that dominates at 3x3.


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _scaled(a, k):
    return (a[0] * k, a[1] * k, a[2] * k)


def _aligned_sum(x, y, z):
    """x + sign(.) y + sign(.) z for parallel (or anti-parallel) vectors, signs chosen so nothing
    cancels: |result|^2 >= |x|^2 + |y|^2 + |z|^2."""
    sy = np.where(_dot(x, y) < 0, -1.0, 1.0)
    c = (x[0] + sy * y[0], x[1] + sy * y[1], x[2] + sy * y[2])
    sz = np.where(_dot(c, z) < 0, -1.0, 1.0)
    return (c[0] + sz * z[0], c[1] + sz * z[1], c[2] + sz * z[2])


def _rotations_closed_form(S: np.ndarray) -> np.ndarray:
    """R = V' U'^T with V' = [v1, v2, v1 x v2], U' = [u1, u2, u1 x u2]: the SVD solution with the
    reflection fix (flipping the least singular pair) without forming v3, u3 or det(V U^T).
    v1, v2: the top eigenvectors of B = S^T S, found in the plane orthogonal to v3 (the least
    one, from cross products of two rows of B - l3 I); rows whose two least eigenvalues nearly
    coincide (where that is unstable) go to LAPACK."""
    N = S.shape[0]
    s = S.reshape(N, 9).T.copy()  # s[3a + b] = S[:, a, b]
    b00 = s[0] * s[0] + s[3] * s[3] + s[6] * s[6]
    b11 = s[1] * s[1] + s[4] * s[4] + s[7] * s[7]
    b22 = s[2] * s[2] + s[5] * s[5] + s[8] * s[8]
    tr = b00 + b11 + b22
    itr = 1.0 / np.maximum(tr, 1e-300)
    b00 *= itr  # trace 1 from here on: the thresholds below are relative
    b11 *= itr
    b22 *= itr
    b01 = (s[0] * s[1] + s[3] * s[4] + s[6] * s[7]) * itr
    b02 = (s[0] * s[2] + s[3] * s[5] + s[6] * s[8]) * itr
    b12 = (s[1] * s[2] + s[4] * s[5] + s[7] * s[8]) * itr
    # least eigenvalue l3 and the gap l2 - l3 (trigonometric formula for symmetric 3x3)
    q = (b00 + b11 + b22) * (1.0 / 3.0)
    d0, d1, d2 = b00 - q, b11 - q, b22 - q
    p2 = (d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * (b01 * b01 + b02 * b02 + b12 * b12)) * (1.0 / 6.0)
    p = np.sqrt(p2)
    det = (d0 * (d1 * d2 - b12 * b12) - b01 * (b01 * d2 - b12 * b02) + b02 * (b01 * b12 - d1 * b02)) / np.maximum(p2 * p, 1e-300)
    cphi = np.cos(np.arccos(np.clip(0.5 * det, -1.0, 1.0)) * (1.0 / 3.0))
    sphi = np.sqrt(np.maximum(1.0 - cphi * cphi, 0.0))
    l3 = q - p * (cphi + np.sqrt(3.0) * sphi)
    gap = (2.0 * np.sqrt(3.0)) * p * sphi
    # v3: cross products of rows of A = B - l3 I are all parallel to it
    a00, a11, a22 = b00 - l3, b11 - l3, b22 - l3
    r0, r1, r2 = (a00, b01, b02), (b01, a11, b12), (b02, b12, a22)
    v3 = _aligned_sum(_cross(r0, r1), _cross(r0, r2), _cross(r1, r2))
    n3 = _dot(v3, v3)
    v3 = _scaled(v3, 1.0 / np.sqrt(np.maximum(n3, 1e-300)))
    # a basis (a, b) of the plane orthogonal to v3, from the rows of A (which span it)
    a = _aligned_sum(r0, r1, r2)
    k = _dot(a, v3)
    a = (a[0] - k * v3[0], a[1] - k * v3[1], a[2] - k * v3[2])
    na = _dot(a, a)
    a = _scaled(a, 1.0 / np.sqrt(np.maximum(na, 1e-300)))
    b = _cross(v3, a)
    # the 2x2 problem in that plane, exact by a Jacobi rotation (half-angle formulas)
    Ba = (b00 * a[0] + b01 * a[1] + b02 * a[2], b01 * a[0] + b11 * a[1] + b12 * a[2], b02 * a[0] + b12 * a[1] + b22 * a[2])
    Bb = (b00 * b[0] + b01 * b[1] + b02 * b[2], b01 * b[0] + b11 * b[1] + b12 * b[2], b02 * b[0] + b12 * b[1] + b22 * b[2])
    m01 = _dot(a, Bb)
    h = _dot(a, Ba) - _dot(b, Bb)
    r = np.sqrt(h * h + 4.0 * m01 * m01)
    c2 = h / np.maximum(r, 1e-300)
    c2 = np.where(r > 0, c2, 1.0)
    ct = np.sqrt(np.maximum(0.5 * (1.0 + c2), 0.0))
    st = np.copysign(np.sqrt(np.maximum(0.5 * (1.0 - c2), 0.0)), m01)
    v1 = (ct * a[0] + st * b[0], ct * a[1] + st * b[1], ct * a[2] + st * b[2])
    v2 = (ct * b[0] - st * a[0], ct * b[1] - st * a[1], ct * b[2] - st * a[2])
    # left singular vectors: u1 = S v1 / s1, u2 = S v2 orthogonalised against u1
    w1 = (s[0] * v1[0] + s[1] * v1[1] + s[2] * v1[2], s[3] * v1[0] + s[4] * v1[1] + s[5] * v1[2], s[6] * v1[0] + s[7] * v1[1] + s[8] * v1[2])
    s1 = np.sqrt(_dot(w1, w1))
    u1 = _scaled(w1, 1.0 / np.maximum(s1, 1e-300))
    w2 = (s[0] * v2[0] + s[1] * v2[1] + s[2] * v2[2], s[3] * v2[0] + s[4] * v2[1] + s[5] * v2[2], s[6] * v2[0] + s[7] * v2[1] + s[8] * v2[2])
    k = _dot(u1, w2)
    w2 = (w2[0] - k * u1[0], w2[1] - k * u1[1], w2[2] - k * u1[2])
    s2 = np.sqrt(_dot(w2, w2))
    u2 = _scaled(w2, 1.0 / np.maximum(s2, 1e-300))
    v3 = _cross(v1, v2)
    u3 = _cross(u1, u2)
    Rt = np.empty((3, 3, N))  # contiguous rows to write; returned as an (N, 3, 3) view
    for i in range(3):
        for j in range(3):
            Rt[i, j] = v1[i] * u1[j] + v2[i] * u2[j] + v3[i] * u3[j]
    R = Rt.transpose(2, 0, 1)
    # unstable rows: l2 ~ l3 (v3 undetermined), rank <= 1 (u2 undetermined) -> LAPACK
    bad = (gap < 1e-6) | (n3 < 1e-24) | (na < 1e-24) | (s2 <= 1e-9 * s1) | ~np.isfinite(tr)
    if np.any(bad):
        idx = np.flatnonzero(bad)
        R[idx] = fit_rotations(S[idx], "svd")
        R[idx[tr[idx] <= 1e-300]] = np.eye(3)  # S = 0: no preference, keep the identity
    return R

