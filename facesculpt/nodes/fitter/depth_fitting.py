"""A fit refined on an aligned depth image (issue 49; seed 002, chapter 5): pose, shape and
expression solved together against the landmarks and a robust point-to-plane term between the
model's visible vertices and the back-projected depth.

Each of ``iterations`` Gauss-Newton steps (linearised about the current fit, the seed's iterative
linearised optimisation):

1. at the first step and at those in ``RESELECT``, the vertices matched are chosen: those whose
   normal (the model mean's, turned with the head) faces the camera (cosine above
   ``FACING_COS``), at most ``MAX_POINTS`` of them spread evenly;
2. each is projected into the depth image (through the depth-to-colour transform and the depth
   camera's K) and paired with the back-projected depth at that pixel (projective data
   association); a pixel without a measurement (0: a hole) and a pair farther apart than the
   step's gate (``GATES_MM``: the background, hair, glasses, another surface in front) is left out;
3. the residuals n . (C - P) (mm, n the model's normal at the vertex) weigh in with Huber weights
   (``HUBER``), beside the landmarks' reprojection residuals (px) and the coefficients' Gaussian
   priors; the step (rotation increment, translation, shape and expression coefficients) solves
   the weighted normal equations.

What a frame's depth says of the shape alone (its normal matrix with the frame's own pose and
expression eliminated) is carried to the next frames as a prior, fading (``SHAPE_DECAY``), so the
sides of the face seen while the head turns stay known.

Arrays in, arrays out: :func:`fit_depth` on plain arrays; :class:`DepthRefiner` holds the model's
prepared bases and the shape evidence, and turns a landmark :class:`~.result.FitResult` into the
refined one (the same type, camera space, perspective only).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from facesculpt.geometry.projection import project
from facesculpt.geometry.vertex_normals import vertex_normals

#: Gauss-Newton steps; the association gate of each (mm; the last one repeats); the steps that
#: choose the vertices matched and their normals anew (the others keep the last choice).
ITERATIONS = 6
RESELECT = (0, 2)
#: The first steps solve the pose alone (cheap: they take out most of a start degrees off).
RIGID_STEPS = 2
GATES_MM = (40.0, 20.0, 12.0, 10.0)
#: Noise scales that whiten the residuals: depth (mm, the sensor's noise and the model's error)
#: and landmarks (px, the detector's error).
SIGMA_DEPTH_MM, SIGMA_LANDMARK_PX = 2.5, 20.0
#: Huber's threshold, in whitened units (1.5 sigma).
HUBER = 1.5
#: Vertices taking part: normal facing the camera at least this much (cosine), at most this many
#: (evenly spread over the candidates, for a bounded cost).
FACING_COS, MAX_POINTS = 0.25, 600
#: The weight of the coefficients' standard normal prior (1: as the model's statistics say; a
#: frame's depth says more of the shape than its noise scale above admits).
COEFFICIENT_PRIOR = 0.3
#: The start's distance is corrected first by the median ratio of measured to modelled depth,
#: over the ratios within this much of 1.
DEPTH_RATIO = 0.2
#: Fewer associated points than this and the depth is not used for the frame.
MIN_POINTS = 60
#: The steps stop early, once the vertices matched are chosen for good and all unknowns are
#: solved, when a step turns the head less than this (rad), moves it less than this (mm) and
#: changes no coefficient more than this (standard deviations): below what the fit resolves.
CONVERGED_RAD, CONVERGED_MM, CONVERGED_SD = 0.003, 0.3, 0.05
#: The shape carried over frames: the share of a frame's evidence of the shape that joins the
#: memory (its points' errors are correlated, and the model is not the face), and the decay of
#: that memory per frame.
SHAPE_SHARE, SHAPE_DECAY = 1.0, 0.95


@dataclass(frozen=True)
class DepthImage:
    """An aligned depth image: depth (DH, DW) uint16 mm along the depth camera's axis (0: none);
    K (3, 3) float64 its intrinsics, px (pixel centres at integer coordinates); depth_to_color
    (4, 4) float64 the rigid transform, mm, from the depth camera's frame to the colour camera's
    (None: identity)."""

    depth: np.ndarray
    K: np.ndarray
    depth_to_color: np.ndarray | None = None

    def points_at(self, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The measured points (N, 3) colour camera mm where points C (N, 3) colour camera mm
        project in the depth image (nearest pixel), and (N,) bool where there is a measurement."""
        C = np.asarray(C, np.float64)
        T = self.depth_to_color
        Cd = C if T is None else (C - T[:3, 3]) @ T[:3, :3]
        K = self.K
        z = np.maximum(Cd[:, 2], 1e-6)
        j = np.rint(K[0, 0] * Cd[:, 0] / z + K[0, 2]).astype(np.int64)
        i = np.rint(K[1, 1] * Cd[:, 1] / z + K[1, 2]).astype(np.int64)
        H, W = self.depth.shape
        inside = (Cd[:, 2] > 0) & (j >= 0) & (j < W) & (i >= 0) & (i < H)
        d = np.zeros(len(C))
        d[inside] = self.depth[i[inside], j[inside]]
        P = np.column_stack([(j - K[0, 2]) / K[0, 0] * d, (i - K[1, 2]) / K[1, 1] * d, d])
        if T is not None:
            P = P @ T[:3, :3].T + T[:3, 3]
        return P, d > 0


@dataclass
class DepthFit:
    """What :func:`fit_depth` returns: R (3, 3), t (3,) mm, alpha (S,), beta (E,) (standard
    deviations), points: depth points associated in the last step (0: the depth was not used),
    rms_mm: their RMS point-to-plane residual, mm; information: what the frame says of the shape
    alone (:func:`_shape_information`: (S, S), (S,)), for the next frames' ``shape_prior``;
    steps: the Gauss-Newton steps taken (fewer than asked when they converged)."""

    R: np.ndarray
    t: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray
    points: int
    rms_mm: float
    information: tuple[np.ndarray, np.ndarray] | None = None
    steps: int = 0


def _candidates(mean, basis, triangles, R, t, c, outward: float, normals=None) -> tuple[np.ndarray, np.ndarray]:
    """The vertices the depth is matched at: those whose normal faces the camera (cosine above
    ``FACING_COS``), at most ``MAX_POINTS`` evenly spread, (M,) indices, and their unit normals
    (M, 3) model space: ``normals`` (V, 3) when given (the posed ``mean`` then decides what faces
    the camera), else those of the current shape."""
    if normals is None:
        X = mean + (basis.reshape(3 * len(mean), len(c)) @ c).reshape(-1, 3)
        n = outward * vertex_normals(X, triangles)
    else:
        X, n = mean, normals
    C = X @ R.T + t
    facing = ((n @ R.T) * C).sum(axis=1) < -FACING_COS * np.linalg.norm(C, axis=1)
    cand = np.flatnonzero(facing)
    if len(cand) > MAX_POINTS:
        cand = cand[np.linspace(0, len(cand) - 1, MAX_POINTS).astype(np.int64)]
    return cand, n[cand]


def _rotation(w: np.ndarray) -> np.ndarray:
    """Rodrigues: the rotation (3, 3) of the rotation vector ``w`` (rad)."""
    th = float(np.linalg.norm(w))
    if th < 1e-12:
        return np.eye(3)
    k = w / th
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * Kx + (1 - np.cos(th)) * Kx @ Kx


def _huber(r: np.ndarray) -> np.ndarray:
    a = np.abs(r)
    return np.where(a <= HUBER, 1.0, HUBER / np.maximum(a, 1e-12))


def _landmark_rows(C: np.ndarray, a: np.ndarray, RB: np.ndarray, K: np.ndarray):
    """d(pixels)/d(step) (2L, 6 + P) and the pixels (L, 2) of landmark points C (L, 3) camera mm,
    a = R L (L, 3), RB (L, 3, P) the rotated basis rows."""
    z = C[:, 2]
    fx, fy = K[0, 0], K[1, 1]
    du = np.zeros((len(C), 2, 3))
    du[:, 0, 0], du[:, 0, 2] = fx / z, -fx * C[:, 0] / z ** 2
    du[:, 1, 1], du[:, 1, 2] = fy / z, -fy * C[:, 1] / z ** 2
    Jc = np.zeros((len(C), 3, 6 + RB.shape[2]))
    ax = np.zeros((len(C), 3, 3))  # -skew(a): the rotation increment's effect
    ax[:, 0, 1], ax[:, 0, 2], ax[:, 1, 2] = a[:, 2], -a[:, 1], a[:, 0]
    ax[:, 1, 0], ax[:, 2, 0], ax[:, 2, 1] = -a[:, 2], a[:, 1], -a[:, 0]
    Jc[:, :, :3] = ax
    Jc[:, :, 3:6] = np.eye(3)
    Jc[:, :, 6:] = RB
    J = np.matmul(du, Jc).reshape(-1, 6 + RB.shape[2])
    return J, project(C, K)


def fit_depth(mean: np.ndarray, basis: np.ndarray, triangles: np.ndarray, R: np.ndarray, t: np.ndarray,
              coefficients: np.ndarray, num_shape: int, landmark_vertices: np.ndarray,
              landmark_weights: np.ndarray, landmark_px: np.ndarray, K: np.ndarray, depth: DepthImage,
              shape_prior: tuple[np.ndarray, np.ndarray] | None = None,
              bounds: tuple[np.ndarray, np.ndarray] | None = None, outward: float = 1.0,
              iterations: int | None = None, normals: np.ndarray | None = None) -> DepthFit:
    """Refine a perspective fit on ``depth`` (see the module docstring).

    mean (V, 3) model mm; basis (V, 3, P) the shape then expression components, mm per standard
    deviation; triangles (T, 3); R (3, 3), t (3,) mm the pose to start from; coefficients (P,) the
    shape (first ``num_shape``) then expression coefficients to start from; landmark_vertices,
    landmark_weights (L, 3) each landmark's model point as vertex triple and barycentric weights;
    landmark_px (L, 2) their detected pixels; K (3, 3) the colour camera; shape_prior: (H (S, S),
    h (S,)) what earlier frames said of the shape, the energy 1/2 a^T H a - h^T a added (the sum
    of their :attr:`DepthFit.information`); bounds: lower, upper (E,) of the expression
    coefficients; outward: +1 when the mesh's corner order makes its normals point out of the
    face, -1 otherwise; iterations: Gauss-Newton steps (None: ``ITERATIONS``); normals (V, 3) model space: fixed normals (e.g. the mean shape's) instead
    of the current shape's, cheaper. Returns a :class:`DepthFit` (the start itself, with
    points = 0, when fewer than ``MIN_POINTS`` depth points associate).
    """
    R, t, c = np.asarray(R, np.float64), np.asarray(t, np.float64), np.asarray(coefficients, np.float64).copy()
    P, S = len(c), num_shape
    lm_v, lm_w = np.asarray(landmark_vertices, np.int64), np.asarray(landmark_weights, np.float64)
    lm_basis = np.einsum("lk,lkdp->ldp", lm_w, basis[lm_v].astype(np.float64))
    lm_flat, lm_mean = lm_basis.reshape(3 * len(lm_v), P), np.einsum("lk,lkd->ld", lm_w, mean[lm_v])
    used, rms, H_data, steps = 0, 0.0, None, 0
    for step in range(ITERATIONS if iterations is None else iterations):
        if step in RESELECT:  # the vertices matched, their normals (model space) and basis rows
            cand, n_c = _candidates(mean, basis, triangles, R, t, c, outward, normals)
            mean_c, basis_c = mean[cand], basis[cand]
            normal_basis = np.einsum("md,mdp->mp", n_c, basis_c)   # n^T R^T R B: the shape columns
            basis_c = basis_c.reshape(3 * len(cand), P)   # one matrix-vector product, not M small ones
        C = (mean_c + (basis_c @ c.astype(basis_c.dtype)).reshape(-1, 3)) @ R.T + t
        if step == 0:
            shift = _along_the_ray(C, depth)
            t, C = t + shift, C + shift
        Pm, valid = depth.points_at(C)
        valid &= np.linalg.norm(Pm - C, axis=1) < GATES_MM[min(step, len(GATES_MM) - 1)]
        if valid.sum() < MIN_POINTS:
            if step == 0:
                return DepthFit(R, t, c[:S], c[S:], 0, 0.0)
            break
        nv = n_c[valid] @ R.T
        r = ((C[valid] - Pm[valid]) * nv).sum(axis=1)   # mm
        k = 6 if step < RIGID_STEPS else 6 + P   # the unknowns: the pose alone first, cheap steps
        Jd = np.column_stack([np.cross(C[valid] - t, nv), nv] + ([normal_basis[valid]] if k > 6 else []))
        Cl = (lm_mean + (lm_flat @ c).reshape(-1, 3)) @ R.T + t
        Jl, ul = _landmark_rows(Cl, Cl - t, np.einsum("ij,ljp->lip", R, lm_basis[:, :, :k - 6]), K)
        rl = (ul - landmark_px).reshape(-1)   # px
        # the whitening (1 / sigma) and the Huber weights in one weight per row
        wd = _huber(r / SIGMA_DEPTH_MM) / SIGMA_DEPTH_MM ** 2
        wl = _huber(rl / SIGMA_LANDMARK_PX) / SIGMA_LANDMARK_PX ** 2
        WJd, WJl = Jd.T * wd, Jl.T * wl
        H_data = WJd @ Jd + WJl @ Jl
        H, g = H_data.copy(), WJd @ r + WJl @ rl
        if k > 6:
            H[6:, 6:] += COEFFICIENT_PRIOR * np.eye(P)
            g[6:] += COEFFICIENT_PRIOR * c
            if shape_prior is not None and S:
                H[6:6 + S, 6:6 + S] += shape_prior[0]
                g[6:6 + S] += shape_prior[0] @ c[:S] - shape_prior[1]
        delta = -np.linalg.solve(H + 1e-6 * np.eye(k), g)
        R, t, c = _rotation(delta[:3]) @ R, t + delta[3:6], c + np.r_[delta[6:], np.zeros(6 + P - k)]
        if bounds is not None and P > S:
            c[S:] = np.clip(c[S:], bounds[0], bounds[1])
        used, rms, steps = int(valid.sum()), float(np.sqrt(np.mean(r ** 2))), step + 1
        if step >= max(RESELECT) and k == 6 + P and _converged(delta):
            break
    return DepthFit(R, t, c[:S], c[S:], used, rms, _shape_information(H_data, S, c[:S]), steps)


def _converged(delta: np.ndarray) -> bool:
    """Whether a step ``delta`` (rotation increment rad, translation mm, coefficients) is below
    ``CONVERGED_RAD``, ``CONVERGED_MM`` and ``CONVERGED_SD``."""
    return (float(np.linalg.norm(delta[:3])) < CONVERGED_RAD and float(np.linalg.norm(delta[3:6])) < CONVERGED_MM
            and float(np.abs(delta[6:]).max(initial=0.0)) < CONVERGED_SD)


def _along_the_ray(C: np.ndarray, depth: DepthImage) -> np.ndarray:
    """The translation (3,) mm that moves posed points C (M, 3) camera mm along the ray through
    their centre to the depth the image measures there: the median ratio of measured to modelled
    depth (landmarks alone leave the distance uncertain by centimetres, more than the first gate),
    over the ratios within ``DEPTH_RATIO`` of 1. Zero when fewer than ``MIN_POINTS`` are."""
    Pm, valid = depth.points_at(C)
    ratio = Pm[valid, 2] / C[valid, 2]
    ratio = ratio[np.abs(ratio - 1.0) < DEPTH_RATIO]
    if len(ratio) < MIN_POINTS:
        return np.zeros(3)
    return (float(np.median(ratio)) - 1.0) * C.mean(axis=0)


def _shape_information(H: np.ndarray | None, S: int, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """What one frame's data says of the shape alone: the Schur complement (S, S) of the shape
    block of the data's normal matrix ``H`` (the pose and expression, the frame's own, eliminated),
    and that matrix times the frame's ``alpha`` (S,)."""
    if H is None or S == 0 or len(H) < 6 + S:
        return None
    s = np.arange(6, 6 + S)
    o = np.r_[np.arange(6), np.arange(6 + S, len(H))]
    Hs = H[np.ix_(s, s)] - H[np.ix_(s, o)] @ np.linalg.solve(H[np.ix_(o, o)] + 1e-6 * np.eye(len(o)), H[np.ix_(o, s)])
    Hs = 0.5 * (Hs + Hs.T)
    return Hs, Hs @ alpha


class DepthRefiner:
    """A fitter's depth refinement: the model's bases prepared once, and what the depth of the
    earlier frames said of the shape (a prior for the next, decaying); :meth:`reset` forgets it."""

    def __init__(self, model, num_shape: int):
        self.model = model
        self.num_shape = int(num_shape)
        m = model
        self.mean = np.asarray(m.mean, np.float64)
        self.basis = np.concatenate([m.shape_basis[:, :, :self.num_shape] * m.shape_std[:self.num_shape],
                                     m.expression_basis * m.expression_std], axis=2).astype(np.float32)
        self.triangles = np.asarray(m.triangles, np.int64)
        n = vertex_normals(self.mean, self.triangles)
        self.outward = 1.0 if float(np.median(((self.mean - self.mean.mean(axis=0)) * n).sum(axis=1))) > 0 else -1.0
        self.normals = self.outward * n
        has_bounds = len(getattr(m, "expression_lower", [])) == m.num_expression and m.num_expression
        self.bounds = (np.asarray(m.expression_lower), np.asarray(m.expression_upper)) if has_bounds else None
        self._matched = None   # (key, keep, take) of :meth:`_matching`
        self.reset()

    def reset(self) -> None:
        self.shape_H = np.zeros((self.num_shape, self.num_shape))
        self.shape_h = np.zeros(self.num_shape)

    def refine(self, result, landmark_px: np.ndarray, landmark_ids: list[str], ids: list[str],
               depth: DepthImage, K: np.ndarray):
        """``result`` (a perspective :class:`~.result.FitResult` of this model) refined on ``depth``:
        the same type with pose, coefficients, vertices and pixels replaced (unchanged when the
        depth has too few points on the face). landmark_px (N, 2) px the frame's points with
        ``ids`` (N,); landmark_ids: the landmark of each of the result's correspondences."""
        lm_v, lm_w = self._landmarks(result, landmark_ids)
        keep, take = self._matching(landmark_ids, ids)
        px = np.asarray(landmark_px, np.float64)[take, :2]
        S = self.num_shape
        coef = np.r_[np.asarray(result.alpha, np.float64)[:S], np.zeros(max(0, S - len(result.alpha))),
                     np.asarray(result.beta, np.float64)]
        fit = fit_depth(self.mean, self.basis, self.triangles, result.R, result.t, coef, S, lm_v[keep], lm_w[keep],
                        px, K, depth, (self.shape_H, self.shape_h), self.bounds, self.outward,
                        normals=self.normals)
        if fit.points == 0:
            return result
        if fit.information is not None:  # the earlier frames' evidence fades; this frame's joins it
            self.shape_H = SHAPE_DECAY * self.shape_H + SHAPE_SHARE * fit.information[0]
            self.shape_h = SHAPE_DECAY * self.shape_h + SHAPE_SHARE * fit.information[1]
        coef = np.r_[fit.alpha, fit.beta]
        X = self.mean + (self.basis.reshape(3 * len(self.mean), len(coef)) @ coef.astype(self.basis.dtype)).reshape(-1, 3)
        C = X @ fit.R.T + fit.t
        proj = project(C, K)
        Cl = np.einsum("lk,lkd->ld", lm_w[keep], C[lm_v[keep]])
        residual = float(np.sqrt(((project(Cl, K) - px) ** 2).sum(axis=1).mean())) if len(keep) else 0.0
        return dataclasses.replace(result, vertices=C.astype(np.float32), projected=proj.astype(np.float32),
                                   R=fit.R, t=fit.t, alpha=fit.alpha.astype(np.float32),
                                   beta=fit.beta.astype(np.float32), model_vertices=X.astype(np.float32),
                                   residual_px=residual)

    def _matching(self, landmark_ids: list[str], ids: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """(K,) the indices of the result's landmarks found among the frame's ``ids`` and (K,) the
        index of each there; the last answer kept (the ids rarely change between frames)."""
        key = (tuple(landmark_ids), tuple(ids))
        if self._matched is None or self._matched[0] != key:
            where = {name: i for i, name in enumerate(ids)}
            keep = np.array([j for j, name in enumerate(landmark_ids) if name in where], np.int64)
            take = np.array([where[landmark_ids[j]] for j in keep], np.int64)
            self._matched = (key, keep, take)
        return self._matched[1], self._matched[2]

    def _landmarks(self, result, landmark_ids: list[str]):
        """The model points (vertex triples (L, 3), barycentric weights (L, 3)) of the result's
        landmarks: its correspondences (sparse), else each landmark id a vertex number (dense)."""
        if result.correspondences is not None:
            v, w = result.correspondences
            return np.asarray(v, np.int64), np.asarray(w, np.float64)
        v = np.array([int(name) for name in landmark_ids], np.int64)
        return np.repeat(v[:, None], 3, axis=1), np.tile([1.0, 0.0, 0.0], (len(v), 1))
