"""As-rigid-as-possible surface deformation (Sorkine & Alexa 2007; the paper's Eq. 4).

A pure module: numpy arrays in, numpy arrays out. The energy of a deformed mesh ``P'`` of
the rest mesh ``P`` is

    E(P') = sum_i sum_{j in N(i)} w_ij || (p'_i - p'_j) - R_i (p_i - p_j) ||^2

with cotangent weights ``w_ij = (cot a_ij + cot b_ij) / 2`` and, per vertex cell, the rotation
``R_i`` that minimises the cell's term (found by SVD of the cell's covariance). The solver
alternates that local step with a global step, a sparse linear solve over the free (ROI)
vertices whose matrix only depends on the anchor set: it is factorised once per anchor set
and reused while only the handle positions move.

The local/global alternation converges slowly (linearly) on its long, smooth modes. By default
each solve is Anderson-accelerated (Peng et al., "Anderson Acceleration for Geometry Optimization
and Physics Simulation", SIGGRAPH 2018): each step extrapolates from the last few local/global
steps, and a step that would raise the energy is replaced by the plain local/global step, so the
energy still never increases. On a nose drag of the Surrey Face Model five accelerated iterations
land closer to the converged mesh than ten plain ones.

Anchor sets (vertex indices into the rest mesh):

* ``static``  - fixed at their rest positions;
* ``handles`` - placed at the positions given to :meth:`ArapDeformer.solve` (moved by the user);
* ``roi``     - free: where the deformation spreads.

Vertices in no set are fixed at their rest positions (outside every ROI nothing moves).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


class DeformerError(ValueError):
    """Bad input to the deformer: indices out of range or not integers, overlapping or
    duplicated anchor sets, an empty ROI, non-finite or wrongly shaped positions, a name
    that is not a landmark of the model, a preset that does not fit the model."""


# ----------------------------------------------------------------------------------------
# Weights, rotations, energy
# ----------------------------------------------------------------------------------------


def cotangent_weights(vertices: np.ndarray, triangles: np.ndarray, clamp: bool = True) -> sp.csr_matrix:
    """Symmetric edge weights ``w_ij = (cot a_ij + cot b_ij) / 2`` of a triangle mesh.

    vertices: (V, 3) float, rest positions. triangles: (T, 3) int.
    clamp: obtuse angles have negative cotangents, which can make the energy non-convex in the
    global step; with ``clamp`` each angle's cotangent is clamped at 0 (and each edge weight
    floored at 1e-8 x the mean weight, so no edge drops out of the mesh graph). Without it
    the weights are exactly those of ``igl.cotmatrix`` (its off-diagonal entries).
    Returns (V, V) csr float64 with zero diagonal.
    """
    V = np.asarray(vertices, dtype=np.float64)
    T = np.asarray(triangles, dtype=np.int64)
    n = V.shape[0]
    rows, cols, vals = [], [], []
    for k in range(3):
        # angle at corner k is opposite edge (k+1, k+2)
        i, j, o = T[:, (k + 1) % 3], T[:, (k + 2) % 3], T[:, k]
        a = V[i] - V[o]
        b = V[j] - V[o]
        cross = np.linalg.norm(np.cross(a, b), axis=1)
        dot = np.einsum("ij,ij->i", a, b)
        cot = dot / np.maximum(cross, 1e-300)
        if clamp:
            cot = np.maximum(cot, 0.0)
        rows += [i, j]
        cols += [j, i]
        vals += [0.5 * cot, 0.5 * cot]
    W = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
    )  # duplicates (the two triangles of an edge) are summed
    W.sum_duplicates()
    if clamp and W.nnz:
        W.data = np.maximum(W.data, 1e-8 * float(np.mean(np.abs(W.data))))
    return W


def fit_rotations(S: np.ndarray, method: str = "fast") -> np.ndarray:
    """Rotations ``R_i`` maximising ``tr(R_i S_i)`` for covariances ``S_i = sum_j w e e'^T``.

    S: (N, 3, 3) float64. Returns (N, 3, 3) proper rotations ``R = V diag(1, 1, det(V U^T)) U^T``
    where ``S = U diag(s) V^T`` (SVD with the reflection fix of Sorkine & Alexa).
    method: ``"svd"`` - numpy's batched LAPACK SVD; ``"fast"`` - the same SVD computed in
    closed form, vectorised over the batch (eigen-decomposition of ``S^T S``, then ``U`` from
    ``S V``), several times faster at this size; the two agree to ~1e-9 (tested).
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


def _edge_list(weights: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    coo = weights.tocoo()
    return coo.row.astype(np.int64), coo.col.astype(np.int64), coo.data.astype(np.float64)


def arap_energy(
    rest: np.ndarray,
    deformed: np.ndarray,
    weights: sp.csr_matrix,
    rotation_method: str = "fast",
) -> float:
    """ARAP energy of ``deformed`` against ``rest`` with the optimal cell rotations.

    rest, deformed: (V, 3) float, same units (mm); weights: (V, V) from :func:`cotangent_weights`.
    Returns ``sum_i sum_j w_ij ||(p'_i - p'_j) - R_i (p_i - p_j)||^2`` in units^2 (every
    undirected edge appears in both of its vertices' cells).
    """
    P = np.asarray(rest, dtype=np.float64)
    Q = np.asarray(deformed, dtype=np.float64)
    i, j, w = _edge_list(weights)
    e = P[i] - P[j]
    f = Q[i] - Q[j]
    S = np.zeros((P.shape[0], 3, 3))
    np.add.at(S, i, w[:, None, None] * e[:, :, None] * f[:, None, :])
    R = fit_rotations(S, rotation_method)
    r = f - np.einsum("nab,nb->na", R[i], e)
    return float(np.sum(w * np.einsum("na,na->n", r, r)))


# ----------------------------------------------------------------------------------------
# The solver
# ----------------------------------------------------------------------------------------


def _index_array(name: str, idx, n: int) -> np.ndarray:
    if idx is None:
        return np.zeros(0, dtype=np.int64)
    a = np.asarray(idx)
    if a.size == 0:
        return np.zeros(0, dtype=np.int64)
    if a.ndim != 1:
        raise DeformerError(f"{name} must be a 1-D array of vertex indices, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.integer):
        if np.issubdtype(a.dtype, np.floating) and np.all(np.isfinite(a)) and np.all(a == np.round(a)):
            a = a.astype(np.int64)
        else:
            raise DeformerError(f"{name} must hold integer vertex indices, got dtype {a.dtype}")
    a = a.astype(np.int64)
    bad = (a < 0) | (a >= n)
    if np.any(bad):
        raise DeformerError(f"{name} has vertex indices out of range 0..{n - 1}: {a[bad][:5].tolist()}")
    if np.unique(a).size != a.size:
        raise DeformerError(f"{name} lists a vertex more than once")
    return a


@dataclass
class _System:
    """Everything that depends on the anchor set only (built by set_anchors, cached)."""

    free: np.ndarray  # (n_f,) free vertex indices
    handles: np.ndarray  # (H,)
    static: np.ndarray  # (S,)
    active: np.ndarray  # (n_a,) vertices whose rotation enters the global step: free + 1-ring
    cov: sp.csr_matrix  # (3 n_a, V): cov @ P' -> covariances (n_a, 3, 3)
    rot_to_rhs: sp.csr_matrix  # (n_f, 3 n_a): rhs part from rotations
    L_fh: sp.csr_matrix  # (n_f, H): coupling to the handles
    rhs_fixed: np.ndarray  # (n_f, 3): coupling to the vertices fixed at rest (negated, moved to rhs)
    spokes: sp.csr_matrix  # (V, V): sum over active cells of w_ij |p'_i - p'_j|^2 = sum(P' * (spokes @ P'))
    rest_spokes: float  # the same sum for the rest mesh: sum over active cells of w_ij |p_i - p_j|^2
    solve: object  # callable: (n_f, 3) -> (n_f, 3)
    factor_ms: float


class _Anderson:
    """Anderson acceleration (type II, Walker & Ni 2011) of a fixed-point iteration x <- G(x) over
    the last ``depth`` steps: x_next = G(x) - dG gamma with gamma minimising |f - dF gamma|, where
    f = G(x) - x and the rows of dF, dG are differences of consecutive f and G(x). The differences
    live in a ring buffer and their Gram matrix is updated one row per step: a step costs a few
    vector operations on top of G."""

    # Extrapolations need weights well above 1, but a combination whose weights sum (in absolute
    # value) past this comes from a nearly degenerate history and lands far from the solution
    # (seen on the nose-drag benchmark: 2e-3 of the diagonal off after two such steps).
    MAX_WEIGHT = 20.0

    def __init__(self, depth: int):
        self.depth = depth
        self.dF: np.ndarray | None = None  # (depth, N) ring buffers
        self.dG: np.ndarray | None = None
        self.gram = np.zeros((depth, depth))
        self.size = 0
        self.head = 0
        self.f_prev: np.ndarray | None = None
        self.g_prev: np.ndarray | None = None

    def restart(self) -> None:
        """Forget the history."""
        self.size = self.head = 0
        self.f_prev = self.g_prev = None

    def begin_solve(self) -> None:
        """A new solve of the same map shifted (new handle positions): keep the history, but form
        no difference with the previous solve's last step."""
        self.f_prev = self.g_prev = None

    def step(self, x: np.ndarray, g: np.ndarray) -> np.ndarray:
        """The next iterate from the current one ``x`` and its image ``g`` = G(x) (same shapes;
        ``g`` is kept, not copied: do not modify it afterwards)."""
        gf = g.reshape(-1)
        f = gf - x.reshape(-1)
        if self.f_prev is not None:
            if self.dF is None or self.dF.shape[1] != f.size:
                self.dF = np.empty((self.depth, f.size))
                self.dG = np.empty((self.depth, f.size))
            k = self.head
            np.subtract(f, self.f_prev, out=self.dF[k])
            np.subtract(gf, self.g_prev, out=self.dG[k])
            self.head = (k + 1) % self.depth
            self.size = min(self.size + 1, self.depth)
            column = self.dF[: self.size] @ self.dF[k]
            self.gram[k, : self.size] = column
            self.gram[: self.size, k] = column
        self.f_prev, self.g_prev = f, gf
        m = self.size
        if m == 0:
            return g
        A = self.gram[:m, :m].copy()
        # A tiny ridge keeps nearly collinear histories solvable.
        A[np.diag_indices_from(A)] += 1e-12 * max(float(np.trace(A)), 1e-300)
        try:
            gamma = np.linalg.solve(A, self.dF[:m] @ f)
        except np.linalg.LinAlgError:
            self.restart()
            return g
        if np.abs(gamma).sum() > self.MAX_WEIGHT:  # an ill-conditioned history: start it again
            self.restart()
            return g
        return (gf - gamma @ self.dG[:m]).reshape(g.shape)


class ArapDeformer:
    """ARAP deformation of one rest mesh with static / handle / ROI anchors.

    >>> d = ArapDeformer(V, F)                       # V (N, 3) float mm, F (T, 3) int
    >>> d.set_anchors(static=s, handles=h, roi=r)    # index arrays; factorises the ROI system
    >>> Vd = d.solve(targets)                        # targets (H, 3) mm -> (N, 3) mm

    Parameters: ``iterations`` local/global iterations per solve (default 10, libigl's);
    ``tolerance`` stop early when no vertex moved more than ``tolerance`` x the bounding-box
    diagonal in one iteration (0 disables); ``clamp_weights`` see :func:`cotangent_weights`;
    ``acceleration`` ``"anderson"`` (default: Anderson acceleration over the last ``history``
    steps, energy-safeguarded) or ``"none"`` (the plain local/global iteration, step for step
    libigl's); ``rotation_method`` see :func:`fit_rotations`; ``solver`` ``"splu"`` (sparse LU of the
    reduced system) or ``"dense"`` (Cholesky of the free block); ``cache_size`` anchor-set
    factorisations kept (undo returns to a cached one).

    Each solve starts from the last solution (warm start); :meth:`reset` forgets it.
    Raises :class:`DeformerError` on bad input; the previous anchors/solution then stay.
    """

    def __init__(
        self,
        vertices: np.ndarray,
        triangles: np.ndarray,
        *,
        iterations: int = 10,
        tolerance: float = 0.0,
        clamp_weights: bool = True,
        rotation_method: str = "fast",
        solver: str = "splu",
        cache_size: int = 8,
        acceleration: str = "anderson",
        history: int = 5,
    ):
        V = np.asarray(vertices, dtype=np.float64)
        T = np.asarray(triangles)
        if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] < 3:
            raise DeformerError(f"vertices must be (V, 3), got {V.shape}")
        if not np.all(np.isfinite(V)):
            raise DeformerError("vertices contain NaN or inf")
        if T.ndim != 2 or T.shape[1] != 3 or T.shape[0] < 1 or not np.issubdtype(T.dtype, np.integer):
            raise DeformerError(f"triangles must be (T, 3) integers, got {T.shape} {T.dtype}")
        if T.min() < 0 or T.max() >= V.shape[0]:
            raise DeformerError("triangles index vertices out of range")
        if solver not in ("splu", "dense"):
            raise DeformerError(f"unknown solver {solver!r} (use 'splu' or 'dense')")
        if acceleration not in ("anderson", "none"):
            raise DeformerError(f"unknown acceleration {acceleration!r} (use 'anderson' or 'none')")
        if int(history) < 1:
            raise DeformerError(f"history must be >= 1, got {history}")
        fit_rotations(np.eye(3)[None], rotation_method)  # validates the name
        self.rest = V
        self.triangles = T.astype(np.int64)
        self.n = V.shape[0]
        self.iterations = int(iterations)
        self.tolerance = float(tolerance)
        self.rotation_method = rotation_method
        self.solver = solver
        self.acceleration = acceleration
        self.history = int(history)
        # Accelerated solves: the energy (units^2) of each accepted iterate, over the cells of the free
        # vertices and their neighbours (the other cells do not change during a solve).
        self.last_energies: list[float] = []
        self.last_restarts = 0  # accelerated solves: extrapolations rejected for raising the energy
        self.last_converged = False  # the last solve stopped below the tolerance (not at the iteration cap)
        self._anderson: tuple[_System, _Anderson] | None = None  # history of the current anchor set
        self.clamp_weights = clamp_weights
        self.diagonal = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
        self.weights = cotangent_weights(V, self.triangles, clamp=clamp_weights)
        W = self.weights
        self.laplacian = (sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W).tocsr()
        self._cache: OrderedDict[tuple, _System] = OrderedDict()
        self._cache_size = int(cache_size)
        self._sys: _System | None = None
        self.current = V.copy()  # last solution (warm start), (V, 3)
        self.last_iterations = 0
        self.last_factor_ms = 0.0

    # -- anchors -------------------------------------------------------------------------

    @property
    def handles(self) -> np.ndarray:
        return np.zeros(0, np.int64) if self._sys is None else self._sys.handles

    @property
    def static(self) -> np.ndarray:
        return np.zeros(0, np.int64) if self._sys is None else self._sys.static

    @property
    def roi(self) -> np.ndarray:
        return np.zeros(0, np.int64) if self._sys is None else self._sys.free

    def set_anchors(self, static=None, handles=None, roi=None) -> None:
        """Choose the anchor sets (index arrays into the rest mesh; disjoint).

        ``roi=None`` frees every vertex that is neither static nor a handle. Factorises the
        reduced system, or reuses the factorisation when this anchor set was seen recently.
        Raises DeformerError for out-of-range, duplicated or overlapping indices, or an empty ROI.
        """
        s = _index_array("static", static, self.n)
        h = _index_array("handles", handles, self.n)
        if roi is None:
            mask = np.ones(self.n, bool)
            mask[s] = False
            mask[h] = False
            r = np.flatnonzero(mask)
        else:
            r = _index_array("roi", roi, self.n)
        for (na, a), (nb, b) in (((("static", s), ("handles", h))), (("static", s), ("roi", r)), (("handles", h), ("roi", r))):
            both = np.intersect1d(a, b)
            if both.size:
                raise DeformerError(f"anchor sets overlap: {na} and {nb} share vertices {both[:5].tolist()}")
        if r.size == 0:
            raise DeformerError("the ROI is empty: no vertex is free to deform")
        key = (np.sort(s).tobytes(), h.tobytes(), np.sort(r).tobytes())
        if key in self._cache:
            self._cache.move_to_end(key)
            self._sys = self._cache[key]
            self.last_factor_ms = 0.0
            return
        sys_ = self._build(s, h, np.sort(r))
        self._cache[key] = sys_
        while len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        self._sys = sys_
        self.last_factor_ms = sys_.factor_ms

    def _build(self, static: np.ndarray, handles: np.ndarray, free: np.ndarray) -> _System:
        import time

        t0 = time.perf_counter()
        n = self.n
        W = self.weights
        L = self.laplacian
        P = self.rest
        is_free = np.zeros(n, bool)
        is_free[free] = True
        # rotations needed: free vertices and their neighbours (their cells hold free edges)
        touch = np.asarray(W[free].sum(axis=0) != 0).ravel() if free.size else np.zeros(n, bool)
        touch |= is_free
        active = np.flatnonzero(touch)
        n_a = active.size
        pos_a = -np.ones(n, np.int64)
        pos_a[active] = np.arange(n_a)
        # covariance operator: S_i[a, b] = sum_j w_ij e_ij[a] (p'_i - p'_j)[b], e = rest edge
        Wa = W[active].tocoo()
        ii = active[Wa.row]
        jj = Wa.col.astype(np.int64)
        w = Wa.data
        e = P[ii] - P[jj]
        # energy of the active cells' spokes: sum_ij w_ij |d_ij|^2 as a quadratic form (both ends of each spoke)
        spokes = sp.csr_matrix(
            (np.concatenate([w, w, -w, -w]), (np.concatenate([ii, jj, ii, jj]), np.concatenate([ii, jj, jj, ii]))),
            shape=(n, n),
        )
        rows = (3 * Wa.row[:, None] + np.arange(3)[None, :]).ravel()  # row 3*i_local + a
        diag_vals = (w[:, None] * e).ravel()
        cov = sp.csr_matrix(
            (
                np.concatenate([diag_vals, -diag_vals]),
                (np.concatenate([rows, rows]), np.concatenate([np.repeat(ii, 3), np.repeat(jj, 3)])),
            ),
            shape=(3 * n_a, n),
        )
        # rhs from rotations: b_i = sum_j w_ij / 2 (R_i + R_j) e_ij for free i
        pos_f = -np.ones(n, np.int64)
        pos_f[free] = np.arange(free.size)
        Wf = W[free].tocoo()
        fi = free[Wf.row]
        fj = Wf.col.astype(np.int64)
        wf = 0.5 * Wf.data
        ef = P[fi] - P[fj]
        r_rows = np.repeat(Wf.row, 3)
        vals = (wf[:, None] * ef).ravel()
        cols_i = (3 * pos_a[fi][:, None] + np.arange(3)[None, :]).ravel()
        cols_j = (3 * pos_a[fj][:, None] + np.arange(3)[None, :]).ravel()
        rot_to_rhs = sp.csr_matrix(
            (np.concatenate([vals, vals]), (np.concatenate([r_rows, r_rows]), np.concatenate([cols_i, cols_j]))),
            shape=(free.size, 3 * n_a),
        )
        Lf = L[free]
        L_ff = Lf[:, free].tocsc()
        L_fh = Lf[:, handles].tocsr()
        fixed = np.ones(n, bool)
        fixed[free] = False
        fixed[handles] = False
        fixed_idx = np.flatnonzero(fixed)
        rhs_fixed = -(Lf[:, fixed_idx] @ P[fixed_idx])
        if self.solver == "dense":
            import scipy.linalg as sla

            try:
                factor = sla.cho_factor(L_ff.toarray(), lower=False, check_finite=False)
            except np.linalg.LinAlgError as exc:
                raise DeformerError(f"the ROI system is singular ({exc})") from exc
            solve = lambda b, f=factor: sla.cho_solve(f, b, check_finite=False)  # noqa: E731
        else:
            try:
                lu = spla.splu(L_ff, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
            except RuntimeError as exc:
                raise DeformerError(f"the ROI system is singular ({exc})") from exc
            solve = lu.solve
        return _System(
            free=free,
            handles=handles,
            static=static,
            active=active,
            cov=cov,
            rot_to_rhs=rot_to_rhs,
            L_fh=L_fh,
            rhs_fixed=rhs_fixed,
            spokes=spokes,
            rest_spokes=float(np.sum(P * (spokes @ P))),
            solve=solve,
            factor_ms=(time.perf_counter() - t0) * 1e3,
        )

    # -- solving -------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget the warm start: the next solve starts from the rest mesh, with no acceleration history."""
        self.current = self.rest.copy()
        self._anderson = None

    def solve(self, handle_positions=None, iterations: int | None = None) -> np.ndarray:
        """Deform: handles to ``handle_positions`` (H, 3) (model space, mm), static and
        non-ROI vertices at rest, ROI vertices by ARAP. ``iterations`` overrides the default.

        Warm-starts from the previous solution. Returns (V, 3) float64 (a copy).
        Raises DeformerError when no anchors are set or the positions are not finite (H, 3).
        """
        sys_ = self._sys
        if sys_ is None:
            raise DeformerError("set_anchors() must be called before solve()")
        H = sys_.handles.size
        if handle_positions is None:
            handle_positions = np.zeros((0, 3))
        X = np.asarray(handle_positions, dtype=np.float64)
        if X.shape != (H, 3):
            raise DeformerError(f"handle_positions must be ({H}, 3), got {X.shape}")
        if not np.all(np.isfinite(X)):
            raise DeformerError("handle_positions contain NaN or inf")
        iters = self.iterations if iterations is None else int(iterations)
        if iters < 0:
            raise DeformerError("iterations must be >= 0")
        Q = self.current.copy()
        fixed = np.ones(self.n, bool)
        fixed[sys_.free] = False
        Q[fixed] = self.rest[fixed]
        Q[sys_.handles] = X
        rhs_const = sys_.rhs_fixed - (sys_.L_fh @ X if H else 0.0)
        free = sys_.free
        n_a = sys_.active.size
        tol = self.tolerance * self.diagonal
        accelerate = self.acceleration == "anderson"
        anderson = None
        if accelerate:
            # The history outlives the solve while the anchor set stays: its secant pairs describe
            # the local/global map, which a handle move only shifts. No pair spans two solves.
            if self._anderson is None or self._anderson[0] is not sys_:
                self._anderson = (sys_, _Anderson(self.history))
            anderson = self._anderson[1]
            anderson.begin_solve()
        energies: list[float] = []
        x = Q[free]
        x_extrapolated = False
        plain = x  # the last plain local/global iterate
        done = restarts = 0
        step = np.inf
        while done < iters:
            Q[free] = x
            S = (sys_.cov @ Q).reshape(n_a, 3, 3)
            R = fit_rotations(S, self.rotation_method)
            if accelerate:
                # The energy of x's cells with their optimal rotations, nearly free from the local
                # step: sum w |e'|^2 + sum w |e|^2 - 2 sum_i tr(R_i S_i) (e rest, e' deformed spokes).
                energy = float(np.sum(Q * (sys_.spokes @ Q)) + sys_.rest_spokes - 2.0 * np.einsum("nab,nba->", R, S))
                if x_extrapolated and energy > energies[-1]:
                    # The extrapolation overshot: take the plain step from the last accepted iterate.
                    restarts += 1
                    anderson.restart()
                    x, x_extrapolated = plain, False
                    continue
                energies.append(energy)
            Xr = np.ascontiguousarray(np.swapaxes(R, 1, 2)).reshape(3 * n_a, 3)
            plain = sys_.solve(sys_.rot_to_rhs @ Xr + rhs_const)
            done += 1
            step = np.max(np.abs(plain - x)) if tol > 0 else np.inf
            if step <= tol or done == iters:
                break
            if accelerate:
                x = anderson.step(x, plain)
                x_extrapolated = anderson.size > 0
            else:
                x = plain
        Q[free] = plain
        self.last_iterations = done
        self.last_converged = step <= tol
        self.last_energies = energies
        self.last_restarts = restarts
        self.current = Q
        return Q.copy()

    def energy(self, deformed: np.ndarray) -> float:
        """ARAP energy (units^2) of a deformed copy (V, 3) of the rest mesh; see :func:`arap_energy`."""
        Q = np.asarray(deformed, dtype=np.float64)
        if Q.shape != self.rest.shape:
            raise DeformerError(f"deformed must be {self.rest.shape}, got {Q.shape}")
        if not np.all(np.isfinite(Q)):
            raise DeformerError("deformed contains NaN or inf")
        return arap_energy(self.rest, Q, self.weights, self.rotation_method)
