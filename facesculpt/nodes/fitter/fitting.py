"""Shape and expression coefficients by regularised linear least squares (paper Eq. 2).

Given a camera and model correspondences (each a barycentric combination of three vertices), the
projected model points are linear in the coefficients c (alpha or beta) once the projection is
linearised at the current estimate:  u(c) ≈ u0 + J · B · (c − c0), with J (2×3) the projection's
Jacobian (px per model unit; exact for the scaled orthographic camera) and B the basis rows of the
correspondence. We minimise

    Σ_l  w_l ‖(u_l(c) − x_l) / ρ_l‖²  +  λ ‖c‖²   (+ accumulated identity evidence, see below)

where ρ_l is the local pixels-per-model-unit scale, so residuals are measured in model units (mm) and
λ (mm²) does not depend on the image resolution or the face's distance: it is the landmark noise
variance (in mm on the face) relative to the unit-variance coefficient prior.

Identity evidence from earlier frames enters as a quadratic (H, g) added to the normal equations;
see :class:`IdentityAccumulator`.
"""

from __future__ import annotations

import numpy as np


def correspondence_rows(basis: np.ndarray, vertices: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Basis rows (L, 3, K) of L correspondences: Σ_k w_lk · basis[v_lk]. basis (V, 3, K);
    vertices (L, 3) int; weights (L, 3)."""
    if basis.shape[2] == 0:
        return np.zeros((len(vertices), 3, 0), basis.dtype)
    g = basis[vertices]  # (L, 3, 3, K)
    return g[:, 0] * weights[:, 0, None, None] + g[:, 1] * weights[:, 1, None, None] + g[:, 2] * weights[:, 2, None, None]


def correspondence_points(points: np.ndarray, vertices: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(L, 3) barycentric points of L correspondences on a (V, 3) vertex array."""
    g = points[vertices]  # (L, 3, 3)
    return g[:, 0] * weights[:, 0, None] + g[:, 1] * weights[:, 1, None] + g[:, 2] * weights[:, 2, None]


def design(jacobians: np.ndarray, rows: np.ndarray, scale: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Whitened design matrix (2L, K): sqrt(w_l) / ρ_l · J_l · B_l. jacobians (L, 2, 3);
    rows (L, 3, K); scale ρ (L,); weights w (L,)."""
    A = np.matmul(jacobians, rows)
    f = np.sqrt(weights) / scale
    return (A * f[:, None, None]).reshape(-1, rows.shape[2])


def whiten(residual_px: np.ndarray, scale: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(L, 2) pixel residuals -> (2L,) whitened residuals in model units."""
    return (residual_px * (np.sqrt(weights) / scale)[:, None]).reshape(-1)


def solve_regularised(
    A: np.ndarray,
    b: np.ndarray,
    lam: float,
    prior_H: np.ndarray | None = None,
    prior_g: np.ndarray | None = None,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
) -> np.ndarray:
    """argmin_c ‖A c − b‖² + λ‖c‖² + cᵀH c − 2 gᵀc, subject to lower ≤ c ≤ upper.

    A (M, K), b (M,), λ ≥ 0; H (K, K) / g (K,) optional accumulated evidence; bounds (K,) with ±inf
    for none. Unbounded: one Cholesky solve. Lower bounds only (blendshapes): non-negative least
    squares on the Cholesky factor; general box: scipy's bounded least squares."""
    K = A.shape[1]
    if K == 0:
        return np.zeros(0)
    Q = A.T @ A + lam * np.eye(K)
    q = A.T @ b
    if prior_H is not None:
        Q = Q + prior_H
        q = q + prior_g
    lo = np.full(K, -np.inf) if lower is None else np.asarray(lower, np.float64)
    hi = np.full(K, np.inf) if upper is None else np.asarray(upper, np.float64)
    return _bounded_quadratic(Q, q, lo, hi)


class IdentityAccumulator:
    """Identity (shape) evidence gathered over frames: Σ_f decay^(n−f) · (A_fᵀA_f, A_fᵀb_f), the normal
    equations of each finished frame's shape solve. Older frames fade with ``decay`` per frame; the
    total weight is capped at ``max_frames`` frames' worth so the identity can still adapt."""

    def __init__(self, num_shape: int, decay: float = 0.98, max_frames: float = 50.0):
        self.H = np.zeros((num_shape, num_shape))
        self.g = np.zeros(num_shape)
        self.weight = 0.0
        self.decay = decay
        self.max_frames = max_frames

    def add(self, A: np.ndarray, b: np.ndarray) -> None:
        self.H = self.decay * self.H + A.T @ A
        self.g = self.decay * self.g + A.T @ b
        self.weight = self.decay * self.weight + 1.0
        if self.weight > self.max_frames:
            f = self.max_frames / self.weight
            self.H *= f
            self.g *= f
            self.weight = self.max_frames

    def reset(self) -> None:
        self.H[:] = 0
        self.g[:] = 0
        self.weight = 0.0

    @property
    def empty(self) -> bool:
        return self.weight == 0.0


def solve_joint(
    A_shape: np.ndarray,
    A_expr: np.ndarray,
    b: np.ndarray,
    shape_lambda: float,
    expression_lambda: float,
    prior_H: np.ndarray | None = None,
    prior_g: np.ndarray | None = None,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The fixed point of alternating "beta given alpha" and "alpha given beta" for one camera:

        argmin ‖A_s α + A_e β − b‖² + λ_s‖α‖² + αᵀHα − 2gᵀα + λ_e‖β‖²,  lower ≤ β ≤ upper,

    solved exactly: α is eliminated, α*(β) = M⁻¹(A_sᵀ(b − A_e β) + g) with M = A_sᵀA_s + λ_s I + H,
    leaving a small bounded problem in β (the Schur complement), solved as in
    :func:`solve_regularised`; then α = α*(β). A_shape (M, S), A_expr (M, E), b (M,)."""
    S, E = A_shape.shape[1], A_expr.shape[1]
    if E == 0:
        return solve_regularised(A_shape, b, shape_lambda, prior_H, prior_g), np.zeros(0)
    if S == 0:
        return np.zeros(0), solve_regularised(A_expr, b, expression_lambda, lower=lower, upper=upper)
    M = A_shape.T @ A_shape + shape_lambda * np.eye(S)
    gs = A_shape.T @ b
    if prior_H is not None:
        M = M + prior_H
        gs = gs + prior_g
    cho = np.linalg.cholesky(0.5 * (M + M.T))
    # M⁻¹ [A_sᵀA_e, gs] through the Cholesky factor.
    AsAe = A_shape.T @ A_expr
    Z = np.linalg.solve(cho.T, np.linalg.solve(cho, np.column_stack([AsAe, gs])))
    Q = A_expr.T @ A_expr + expression_lambda * np.eye(E) - AsAe.T @ Z[:, :E]
    q = A_expr.T @ b - AsAe.T @ Z[:, E]
    beta = _bounded_quadratic(Q, q, lower, upper)
    alpha = Z[:, E] - Z[:, :E] @ beta
    return alpha, beta


def _bounded_quadratic(Q: np.ndarray, q: np.ndarray, lower, upper) -> np.ndarray:
    """argmin ½cᵀQc − qᵀc subject to lower ≤ c ≤ upper (Q symmetric positive definite)."""
    K = len(q)
    lo = np.full(K, -np.inf) if lower is None else np.asarray(lower, np.float64)
    hi = np.full(K, np.inf) if upper is None else np.asarray(upper, np.float64)
    Q = 0.5 * (Q + Q.T) + 1e-12 * max(np.trace(Q), 1e-30) / K * np.eye(K)
    if not np.isfinite(lo).any() and not np.isfinite(hi).any():
        return np.linalg.solve(Q, q)
    # Imported here, not at the top: a fitter that never bounds its coefficients (the dense one)
    # starts without scipy, which would lengthen a respawned fitter's time away.
    from scipy.optimize import lsq_linear, nnls

    L = np.linalg.cholesky(Q)
    M = L.T
    y = np.linalg.solve(L, q)
    if not np.isfinite(hi).any() and np.isfinite(lo).all():
        d, _ = nnls(M, y - M @ lo)
        return lo + d
    return lsq_linear(M, y, bounds=(lo, hi), method="bvls").x
