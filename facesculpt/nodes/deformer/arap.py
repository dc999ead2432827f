"""The as-rigid-as-possible surface deformation solver (Sorkine & Alexa 2007; the paper's Eq. 4).

A pure module: numpy arrays in, numpy arrays out. It minimises the ARAP energy of
:mod:`.energy` (cotangent weights) by alternating a local step, the per-cell rotations of
:mod:`.rotations`, with a global step, a sparse linear solve over the free (ROI) vertices
whose matrix only depends on the anchor set: it is factorised once per anchor set and
reused while only the handle positions move.

The local/global alternation converges slowly (linearly) on its long, smooth modes. By default
each solve is Anderson-accelerated (:mod:`.anderson`): each step extrapolates from the last few
local/global steps, and a step that would raise the energy is replaced by the plain
local/global step, so the energy still never increases.

Anchor sets (vertex indices into the rest mesh):

* ``static``  - fixed at their rest positions;
* ``handles`` - placed at the positions given to :meth:`ArapDeformer.solve` (moved by the user);
* ``roi``     - free: where the deformation spreads.

Vertices in no set are fixed at their rest positions (outside every ROI nothing moves).
"""

from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .anderson import AndersonAcceleration
from .energy import arap_energy, cotangent_weights
from .errors import DeformerError
from .rotations import fit_rotations


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


def _handle_positions(positions, n_handles: int) -> np.ndarray:
    """The handles' target positions as (H, 3) float64; DeformerError unless finite and (H, 3)."""
    X = np.asarray(np.zeros((0, 3)) if positions is None else positions, dtype=np.float64)
    if X.shape != (n_handles, 3):
        raise DeformerError(f"handle_positions must be ({n_handles}, 3), got {X.shape}")
    if not np.all(np.isfinite(X)):
        raise DeformerError("handle_positions contain NaN or inf")
    return X


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
    cov_spokes: sp.csr_matrix  # (3 n_a + V, V): cov over spokes, one product for both per iteration
    rest_spokes: float  # the same sum for the rest mesh: sum over active cells of w_ij |p_i - p_j|^2
    solve: object  # callable: (n_f, 3) -> (n_f, 3)
    factor_ms: float


# -- the global step's operators, built once per anchor set ------------------------------------


def _active_cells(weights: sp.csr_matrix, free: np.ndarray) -> np.ndarray:
    """Vertices whose rotation enters the global step (V_a,) int64: the free vertices and their
    neighbours (their cells hold free edges)."""
    n = weights.shape[0]
    is_free = np.zeros(n, bool)
    is_free[free] = True
    touch = np.asarray(weights[free].sum(axis=0) != 0).ravel() if free.size else np.zeros(n, bool)
    touch |= is_free
    return np.flatnonzero(touch)


def _cell_spokes(weights: sp.csr_matrix, cells: np.ndarray):
    """The spokes (directed edges i -> j) of the cells ``cells`` (C,): per spoke the cell's
    position in ``cells``, i = cells[position], j and w_ij; each (E,)."""
    coo = weights[cells].tocoo()
    return coo.row, cells[coo.row], coo.col.astype(np.int64), coo.data


def _spoke_energy_form(i: np.ndarray, j: np.ndarray, w: np.ndarray, n: int) -> sp.csr_matrix:
    """(V, V) quadratic form of the spokes' energy: sum w_ij |p'_i - p'_j|^2 = sum(P' * (form @ P'))
    (both ends of each spoke)."""
    return sp.csr_matrix(
        (np.concatenate([w, w, -w, -w]), (np.concatenate([i, j, i, j]), np.concatenate([i, j, j, i]))),
        shape=(n, n),
    )


def _covariance_operator(cell: np.ndarray, i: np.ndarray, j: np.ndarray, w: np.ndarray,
                         rest: np.ndarray, n_cells: int) -> sp.csr_matrix:
    """(3 C, V) operator from deformed positions P' (V, 3) to the cells' covariances
    (C, 3, 3): S_i[a, b] = sum_j w_ij e_ij[a] (p'_i - p'_j)[b], e the rest spoke."""
    e = rest[i] - rest[j]
    rows = (3 * cell[:, None] + np.arange(3)[None, :]).ravel()  # row 3*i_local + a
    diag_vals = (w[:, None] * e).ravel()
    return sp.csr_matrix(
        (
            np.concatenate([diag_vals, -diag_vals]),
            (np.concatenate([rows, rows]), np.concatenate([np.repeat(i, 3), np.repeat(j, 3)])),
        ),
        shape=(3 * n_cells, rest.shape[0]),
    )


def _rotation_rhs_operator(weights: sp.csr_matrix, rest: np.ndarray, free: np.ndarray,
                           active: np.ndarray) -> sp.csr_matrix:
    """(F, 3 V_a) operator from the active cells' rotations, stacked as (3 V_a, 3) rows of
    R^T, to the global step's right-hand side b_i = sum_j w_ij / 2 (R_i + R_j) e_ij, i free."""
    pos_a = -np.ones(rest.shape[0], np.int64)
    pos_a[active] = np.arange(active.size)
    cell, fi, fj, w = _cell_spokes(weights, free)
    wf = 0.5 * w
    ef = rest[fi] - rest[fj]
    r_rows = np.repeat(cell, 3)
    vals = (wf[:, None] * ef).ravel()
    cols_i = (3 * pos_a[fi][:, None] + np.arange(3)[None, :]).ravel()
    cols_j = (3 * pos_a[fj][:, None] + np.arange(3)[None, :]).ravel()
    return sp.csr_matrix(
        (np.concatenate([vals, vals]), (np.concatenate([r_rows, r_rows]), np.concatenate([cols_i, cols_j]))),
        shape=(free.size, 3 * active.size),
    )


def _factorise(L_ff: sp.csc_matrix, solver: str):
    """A solve (F, 3) -> (F, 3) with the free block L_ff (F, F) of the Laplacian, factorised
    once: ``"splu"`` sparse LU, ``"dense"`` Cholesky. DeformerError when it is singular."""
    if solver == "dense":
        try:
            factor = sla.cho_factor(L_ff.toarray(), lower=False, check_finite=False)
        except np.linalg.LinAlgError as exc:
            raise DeformerError(f"the ROI system is singular ({exc})") from exc
        return lambda b: sla.cho_solve(factor, b, check_finite=False)
    try:
        lu = spla.splu(L_ff, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    except RuntimeError as exc:
        raise DeformerError(f"the ROI system is singular ({exc})") from exc
    return lu.solve


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
        self.last_converged = False  # the last solve stopped below the tolerance (not at the iteration cap)
        self._anderson: tuple[_System, AndersonAcceleration] | None = None  # history of the current anchor set
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
        t0 = time.perf_counter()
        n, P = self.n, self.rest
        active = _active_cells(self.weights, free)
        cell, i, j, w = _cell_spokes(self.weights, active)
        spokes = _spoke_energy_form(i, j, w, n)
        Lf = self.laplacian[free]
        fixed = np.ones(n, bool)
        fixed[free] = False
        fixed[handles] = False
        fixed_idx = np.flatnonzero(fixed)
        cov = _covariance_operator(cell, i, j, w, P, active.size)
        return _System(
            free=free,
            handles=handles,
            static=static,
            active=active,
            cov=cov,
            rot_to_rhs=_rotation_rhs_operator(self.weights, P, free, active),
            L_fh=Lf[:, handles].tocsr(),
            rhs_fixed=-(Lf[:, fixed_idx] @ P[fixed_idx]),
            spokes=spokes,
            cov_spokes=sp.vstack([cov, spokes]).tocsr(),
            rest_spokes=float(np.sum(P * (spokes @ P))),
            solve=_factorise(Lf[:, free].tocsc(), self.solver),
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
        X = _handle_positions(handle_positions, H)
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
                self._anderson = (sys_, AndersonAcceleration(self.history))
            anderson = self._anderson[1]
            anderson.begin_solve()
        energies: list[float] = []
        x = Q[free]
        x_extrapolated = False
        plain = x  # the last plain local/global iterate
        done = 0
        step = np.inf
        while done < iters:
            Q[free] = x
            if accelerate:  # the covariances and the spokes' products in one sparse product
                CQ = sys_.cov_spokes @ Q
                S = CQ[: 3 * n_a].reshape(n_a, 3, 3)
            else:
                S = (sys_.cov @ Q).reshape(n_a, 3, 3)
            R = fit_rotations(S, self.rotation_method)
            if accelerate:
                # The energy of x's cells with their optimal rotations, nearly free from the local
                # step: sum w |e'|^2 + sum w |e|^2 - 2 sum_i tr(R_i S_i) (e rest, e' deformed spokes).
                energy = float(np.sum(Q * CQ[3 * n_a :]) + sys_.rest_spokes - 2.0 * np.einsum("nab,nba->", R, S))
                if x_extrapolated and energy > energies[-1]:
                    # The extrapolation overshot: take the plain step from the last accepted iterate.
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
