"""The Fitter: a morphable model fitted to 2D landmarks, frame after frame (DESIGN.md stage 2).

Sparse mode (models with bases, e.g. the SFM and 68 iBUG landmarks), per frame:

1. pose from the current shape at the landmark correspondences (scaled orthographic, or perspective
   with the intrinsics K; warm-started from the previous frame);
2. outline correspondences for the outline landmarks (:mod:`.outline`: visible outline candidates,
   ray-triangle point);
3. expression beta by bounded regularised least squares given alpha (:mod:`.fitting`);
4. shape alpha likewise given beta, with the identity evidence of earlier frames;

alternated ``iterations`` times, then a last pose update. Identity alpha accumulates across frames
(:class:`.fitting.IdentityAccumulator`) while pose and beta follow each frame; the pose and beta of
the result are smoothed over time by One Euro filters (:mod:`.smoothing`).

Dense mode (``model.dense``, the built-in facemesh): the 468 network points (x, y px; z relative
depth in pixel scale) observe every vertex. The pose is a weighted, robustly re-weighted similarity
Procrustes of the neutral reference onto the points; the fitted mesh is the observation itself (in
camera space: back-projected through K at the pose's depth, or pixel scale under orthographic); the
neutral reference of this person is learned as the running mean, in model space, of the first
``neutral_frames`` frames (then frozen; :attr:`Fitter.neutral_version` counts its changes).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facesculpt.geometry.projection import project
from facesculpt.nodes.fitter import fitting, pose
from facesculpt.nodes.fitter import outline as outline_corr
from facesculpt.nodes.fitter.model import MorphableModel, load_model, normalise_facemesh_neutral
from facesculpt.nodes.fitter.smoothing import OneEuroFilter


class FitError(ValueError):
    """A fit was refused: bad input (NaN, too few or unknown landmarks, degenerate configuration,
    bad image size or intrinsics). The message says which."""


@dataclass
class FitResult:
    """One frame's fit. Camera space is OpenCV's (x right, y down, z away from the camera).

    vertices (V, 3) float32 camera space: mm under ``"perspective"``, pixel scale under
    ``"orthographic"`` (x, y are then pixels and z depth in px); projected (V, 2) float32 pixels;
    R (3, 3) model-to-camera rotation; t (3,) translation (mm, or px with t[2] = 0); scale: px per
    model mm (orthographic) or 1.0 (perspective); alpha (S,), beta (E,) float32 in standard
    deviations; residual_px: RMS landmark reprojection error of the fit (before smoothing);
    model_vertices (V, 3) float32 the fitted shape in model space (mm)."""

    vertices: np.ndarray
    projected: np.ndarray
    R: np.ndarray
    t: np.ndarray
    scale: float
    alpha: np.ndarray
    beta: np.ndarray
    residual_px: float
    projection: str
    K: np.ndarray | None
    model_vertices: np.ndarray
    landmarks_used: int = 0
    correspondences: tuple[np.ndarray, np.ndarray] = field(default=None, repr=False)

    @property
    def yaw_pitch_roll(self) -> tuple[float, float, float]:
        """Head yaw, pitch, roll in degrees (:func:`.pose.euler_from_rotation`)."""
        return pose.euler_from_rotation(self.R)


def _image_size(image_size) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in image_size)
    except (TypeError, ValueError):
        raise FitError(f"image_size must be (W, H), got {image_size!r}") from None
    if w <= 0 or h <= 0:
        raise FitError(f"image_size must be positive, got {w}x{h}")
    return w, h


class Fitter:
    """Fit ``model`` (a :class:`MorphableModel`, "facemesh" or a .npz path) to landmarks.

    image_size (W, H) px; K (3, 3) intrinsics or None; projection "perspective" (needs K; default
    when K is given) or "orthographic" (default without K); iterations of the alternation;
    shape_lambda / expression_lambda: λ of Eq. 2 in mm² (see :mod:`.fitting`); outline "ray"
    (the paper's ray-triangle correspondences), "nearest" (nearest vertex) or "off"; coefficients
    "joint" (per iteration, the fixed point of the beta-given-alpha / alpha-given-beta alternation,
    solved exactly, :func:`.fitting.solve_joint`) or "alternate" (one beta then one alpha solve per
    iteration, as eos does); inner_steps: pose/coefficient alternations per iteration (the outline
    correspondences are updated once per iteration); outline_weight: weight of an outline landmark
    relative to a fixed one (they slide along the silhouette and are annotated less precisely);
    num_shape: how many leading shape components to fit (default all); accumulate_identity: keep
    identity evidence across frames; smoothing: One Euro filtering of pose and expression
    (smooth_min_cutoff Hz; smooth_beta Hz per unit/s for rotation (rad), scale and expression;
    smooth_beta_mm Hz per mm/s for translation and dense vertices); neutral_frames: frames
    averaged into the learned neutral (dense mode); tracking_iterations: iterations when the fit is
    warm-started from the previous frame (the pose, shape and expression are then already close: one
    iteration reaches the landmark error of five within 0.01 px on the shared s18 video, 2.037 against
    2.028 px median, in a quarter of the time; None: always ``iterations``). Thresholds are documented
    where they are used."""

    def __init__(
        self,
        model: MorphableModel | str = "facemesh",
        image_size=(640, 480),
        K: np.ndarray | None = None,
        projection: str | None = None,
        iterations: int = 5,
        tracking_iterations: int | None = 1,
        shape_lambda: float = 3.0,
        expression_lambda: float = 4.0,
        outline: str = "ray",
        coefficients: str = "joint",
        inner_steps: int = 3,
        outline_weight: float = 0.3,
        num_shape: int | None = None,
        min_landmarks: int = 6,
        accumulate_identity: bool = True,
        identity_decay: float = 0.98,
        identity_max_frames: float = 50.0,
        smoothing: bool = True,
        smooth_min_cutoff: float = 1.5,
        smooth_beta: float = 0.5,
        smooth_beta_mm: float = 0.05,
        neutral_frames: int = 30,
        warm_start_gap_s: float = 0.5,
    ):
        self.model = model if isinstance(model, MorphableModel) else load_model(model)
        self.image_size = _image_size(image_size)
        if K is not None:
            try:
                K = pose.check_intrinsics(K)
            except pose.PoseError as exc:
                raise FitError(str(exc)) from None
        self.K = K
        if projection is None:
            projection = "perspective" if K is not None else "orthographic"
        if projection not in ("perspective", "orthographic"):
            raise FitError(f"projection must be 'perspective' or 'orthographic', got {projection!r}")
        if projection == "perspective" and K is None:
            raise FitError("perspective projection needs the intrinsics K")
        self.projection = projection
        if int(iterations) < 1:
            raise FitError(f"iterations must be >= 1, got {iterations}")
        self.iterations = int(iterations)
        if tracking_iterations is not None and int(tracking_iterations) < 1:
            raise FitError(f"tracking_iterations must be >= 1 (or None), got {tracking_iterations}")
        self.tracking_iterations = self.iterations if tracking_iterations is None else min(self.iterations, int(tracking_iterations))
        if shape_lambda < 0 or expression_lambda < 0:
            raise FitError("shape_lambda and expression_lambda must be >= 0")
        self.shape_lambda = float(shape_lambda)
        self.expression_lambda = float(expression_lambda)
        if outline not in ("ray", "nearest", "off"):
            raise FitError(f"outline must be 'ray', 'nearest' or 'off', got {outline!r}")
        self.outline_mode = outline
        if coefficients not in ("joint", "alternate"):
            raise FitError(f"coefficients must be 'joint' or 'alternate', got {coefficients!r}")
        self.coefficients = coefficients
        self.inner_steps = max(1, int(inner_steps))
        if outline_weight <= 0:
            raise FitError("outline_weight must be > 0")
        self.outline_weight = float(outline_weight)
        self.min_landmarks = max(4, int(min_landmarks))
        self.accumulate_identity = accumulate_identity
        self.smoothing = smoothing
        self.smooth_min_cutoff = smooth_min_cutoff
        self.smooth_beta = smooth_beta
        self.smooth_beta_mm = smooth_beta_mm
        self.neutral_frames = int(neutral_frames)
        self.warm_start_gap_s = warm_start_gap_s

        m = self.model
        S = m.num_shape if num_shape is None else max(0, min(int(num_shape), m.num_shape))
        self.num_shape = S
        # Bases pre-scaled by their standard deviations: a coefficient of 1 is one sigma.
        self._shape_basis = (m.shape_basis[:, :, :S] * m.shape_std[:S]).astype(np.float64)
        self._expr_basis = (m.expression_basis * m.expression_std).astype(np.float64)
        self._mean = m.mean.astype(np.float64)
        V = m.num_vertices
        self._full_basis = np.concatenate([self._shape_basis, self._expr_basis], axis=2).reshape(3 * V, -1).astype(np.float32)
        self._names = m.landmark_index()
        self._outline_side: dict[str, int] = {}
        for n in m.outline_landmarks_right:
            self._outline_side[n] = 0
        for n in m.outline_landmarks_left:
            self._outline_side[n] = 1
        self._bands: list[np.ndarray] = []
        self._geometry = None
        if not m.dense and len(m.outline_right) and len(m.outline_left):
            nose = outline_corr.nose_region(m.mean, self._names)
            self._bands = [outline_corr.outline_band(m.mean, m.outline_right, nose),
                           outline_corr.outline_band(m.mean, m.outline_left, nose)]
            cands = np.unique(np.r_[self._bands[0], self._bands[1]])
            self._geometry = outline_corr.OutlineGeometry(m.triangles, cands, V, transparent=nose)
            self._band_pos = [np.searchsorted(cands, b) for b in self._bands]
            edges = m.mean[m.triangles[:, [1, 2, 0]]] - m.mean[m.triangles]
            self._edge_mm = float(np.linalg.norm(edges, axis=2).mean())
        self.identity = fitting.IdentityAccumulator(S, identity_decay, identity_max_frames)
        self.neutral_version = 0
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget everything learned from earlier frames: warm start, identity, filters, neutral."""
        self.identity.reset()
        self._alpha = np.zeros(self.num_shape)
        self._beta = np.zeros(self.model.num_expression)
        self._pose = None  # (R, t, s) of the previous frame
        self._last_time = None
        self._frame = 0
        self._filters = {k: OneEuroFilter(self.smooth_min_cutoff, self.smooth_beta) for k in ("rot", "s", "beta")}
        for k in ("t", "dense"):  # millimetre-valued signals
            self._filters[k] = OneEuroFilter(self.smooth_min_cutoff, self.smooth_beta_mm)
        self._neutral_sum = None
        self._neutral_count = 0
        self._neutral_frozen = False

    @property
    def neutral(self) -> np.ndarray:
        """(V, 3) float32 the neutral model of this person, model space (mm): the model mean plus the
        accumulated identity (sparse), or the learned reference (dense)."""
        if self.model.dense:
            return self.model.mean
        return self.model.instance(self._alpha.astype(np.float32))

    @property
    def frames_fitted(self) -> int:
        """Frames fitted since the last :meth:`reset`."""
        return self._frame

    @property
    def neutral_ready(self) -> bool:
        """Dense mode: the learned neutral reference is complete (frozen)."""
        return self._neutral_frozen if self.model.dense else True

    # ------------------------------------------------------------------ input
    def _parse(self, points2d, ids, weights):
        pts = np.asarray(points2d, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] not in (2, 3):
            raise FitError(f"points must be (N, 2) or (N, 3), got shape {pts.shape}")
        n = len(pts)
        m = self.model
        if ids is None:
            if m.dense and n == m.num_vertices:
                ids = [str(i) for i in range(n)]
            elif n == 68 and "31" in self._names:
                ids = [str(i) for i in range(1, 69)]
            else:
                raise FitError(f"ids are needed for {n} points (model {m.model_id}: give one landmark name per point)")
        ids = [str(int(i)) if isinstance(i, (int, np.integer)) else str(i) for i in ids]
        if len(ids) != n:
            raise FitError(f"{n} points but {len(ids)} ids")
        w = np.ones(n) if weights is None else np.asarray(weights, np.float64).reshape(-1)
        if w.shape != (n,):
            raise FitError(f"weights must be ({n},), got {w.shape}")
        finite = np.isfinite(pts[:, :2]).all(axis=1) & np.isfinite(w) & (w > 0)
        return pts, ids, w, finite

    # ------------------------------------------------------------------ API
    def fit(self, points2d: np.ndarray, ids=None, weights: np.ndarray | None = None, stamp: float | None = None) -> FitResult:
        """Fit one frame. points2d (N, 2) px (or (N, 3) with relative depth, used in dense mode);
        ids: the model landmark each point belongs to (iBUG numbers 1..68 for the SFM, vertex
        numbers 0..467 for facemesh; None for those two defaults); weights (N,) optional confidence;
        stamp: the frame time in seconds (for smoothing and warm start; default 1/30 s per call).
        Points with NaN, non-positive weight or an unknown id are ignored; raises :class:`FitError`
        when too few usable ones remain or they are degenerate."""
        pts, ids, w, finite = self._parse(points2d, ids, weights)
        now = float(stamp) if stamp is not None else (self._last_time + 1 / 30 if self._last_time is not None else 0.0)
        if self._last_time is not None and (now - self._last_time > self.warm_start_gap_s or now < self._last_time):
            self._pose = None  # too long since the last frame (or time went back): start cold
            for f in self._filters.values():
                f.reset()
        try:
            if self.model.dense:
                result = self._fit_dense(pts, ids, w, finite, now)
            else:
                result = self._fit_sparse(pts, ids, w, finite, now)
        except pose.PoseError as exc:
            raise FitError(str(exc)) from None
        except np.linalg.LinAlgError as exc:
            raise FitError(f"the fit is numerically degenerate: {exc}") from None
        self._last_time = now
        self._frame += 1
        return result

    # ------------------------------------------------------------------ camera helpers
    def _camera(self, X: np.ndarray, R, t, s):
        """Model points (N, 3) -> camera points (N, 3), pixels (N, 2)."""
        if self.projection == "orthographic":
            C = s * (X @ R.T) + t
            return C, C[:, :2].copy()
        C = X @ R.T + t
        if (C[:, 2] <= 1e-6).any():
            raise pose.PoseError("the fitted face falls behind the camera")
        return C, project(C, self.K)

    def _linearisation(self, C: np.ndarray, R, s):
        """Jacobians (L, 2, 3) of pixels w.r.t. model points and the local px-per-mm scale (L,)."""
        if self.projection == "orthographic":
            J = np.broadcast_to(s * R[:2], (len(C), 2, 3))
            return J, np.full(len(C), s)
        Jp = pose.projection_jacobian(C, self.K)
        f = 0.5 * (self.K[0, 0] + self.K[1, 1])
        return Jp @ R, f / C[:, 2]

    def _estimate_pose(self, X, x, w, init):
        if self.projection == "orthographic":
            return pose.scaled_orthographic(X, x, w, None if init is None else (init[0], init[2]))
        R, t = pose.perspective(X, x, self.K, w, None if init is None else (init[0], init[1]))
        return R, t, 1.0

    # ------------------------------------------------------------------ sparse
    def _fit_sparse(self, pts, ids, w, finite, now) -> FitResult:
        m = self.model
        fixed_idx, fixed_vert, out_idx, out_side = [], [], [], []
        for i, name in enumerate(ids):
            if not finite[i]:
                continue
            if name in self._outline_side:
                if self.outline_mode != "off" and self._geometry is not None:
                    out_idx.append(i)
                    out_side.append(self._outline_side[name])
            elif name in self._names:
                fixed_idx.append(i)
                fixed_vert.append(self._names[name])
        fixed_idx = np.asarray(fixed_idx, int)
        out_idx = np.asarray(out_idx, int)
        out_side = np.asarray(out_side, int)
        usable = len(fixed_idx) + len(out_idx)
        if len(fixed_idx) < self.min_landmarks:
            known = sum(1 for i, n in enumerate(ids) if finite[i] and (n in self._names or n in self._outline_side))
            raise FitError(
                f"only {len(fixed_idx)} usable landmarks with fixed model vertices ({known} valid of {len(ids)} given; "
                f"at least {self.min_landmarks} are needed)"
            )
        x_fixed = pts[fixed_idx, :2]
        w_fixed = w[fixed_idx]
        x_out = pts[out_idx, :2]
        w_out = w[out_idx] * self.outline_weight
        n_fixed = len(fixed_idx)
        # Correspondences: fixed ones are (v, v, v) with weights (1, 0, 0).
        fv = np.repeat(np.asarray(fixed_vert, int)[:, None], 3, axis=1)
        fw = np.tile([1.0, 0.0, 0.0], (n_fixed, 1))
        cv, cw = fv, fw
        x_all, w_all = x_fixed, w_fixed

        alpha = self._alpha.copy()
        beta = self._beta.copy()
        init = self._pose
        prior = (self.identity.H, self.identity.g) if (self.accumulate_identity and not self.identity.empty) else (None, None)

        def shape_points(verts, weights_):
            base = fitting.correspondence_points(self._mean, verts, weights_)
            rows_s = fitting.correspondence_rows(self._shape_basis, verts, weights_)
            rows_e = fitting.correspondence_rows(self._expr_basis, verts, weights_)
            return base, rows_s, rows_e

        base, rows_s, rows_e = shape_points(cv, cw)
        R, t, s = self._estimate_pose(base + rows_s @ alpha + rows_e @ beta, x_all, w_all, init)
        for _ in range(self.iterations if init is None else self.tracking_iterations):
            if len(out_idx):
                cv, cw, x_all, w_all = self._with_outline(fv, fw, x_fixed, w_fixed, x_out, w_out, out_side, alpha, beta, R, t, s)
                base, rows_s, rows_e = shape_points(cv, cw)
            # With the correspondences fixed, pose and coefficients are alternated a few times:
            # cheap small solves that take most of the slow pose-shape coupling out of each iteration.
            for _ in range(self.inner_steps):
                X = base + rows_s @ alpha + rows_e @ beta
                C, u0 = self._camera(X, R, t, s)
                J, rho = self._linearisation(C, R, s)
                alpha, beta = self._solve_coefficients(J, rho, rows_s, rows_e, x_all, w_all, u0, alpha, beta, prior)
                R, t, s = self._estimate_pose(base + rows_s @ alpha + rows_e @ beta, x_all, w_all, (R, t, s))
        # The frame's residual and identity evidence at the final pose and coefficients.
        X = base + rows_s @ alpha + rows_e @ beta
        C, u0 = self._camera(X, R, t, s)
        residual = float(np.sqrt(((u0 - x_all) ** 2).sum(1).mean()))
        if self.accumulate_identity and self.num_shape:
            J, rho = self._linearisation(C, R, s)
            A = fitting.design(J, rows_s, rho, w_all)
            b = fitting.whiten(x_all - u0, rho, w_all) + A @ alpha
            self.identity.add(A, b)
        self._alpha, self._beta, self._pose = alpha, beta, (R, t, s)

        if self.smoothing:
            R, t, s, beta = self._smooth(R, t, s, beta, now)
        coef = np.r_[alpha, beta].astype(np.float32)
        model_vertices = (m.mean.reshape(-1) + self._full_basis @ coef).reshape(-1, 3)
        Cv, proj = self._camera(model_vertices.astype(np.float64), R, t, s)
        return FitResult(
            vertices=Cv.astype(np.float32), projected=proj.astype(np.float32), R=R, t=t, scale=float(s),
            alpha=alpha.astype(np.float32), beta=np.asarray(beta, np.float32), residual_px=residual,
            projection=self.projection, K=self.K, model_vertices=model_vertices.astype(np.float32),
            landmarks_used=usable, correspondences=(cv, cw),
        )

    def _solve_coefficients(self, J, rho, rows_s, rows_e, x_all, w_all, u0, alpha, beta, prior):
        """alpha, beta for fixed camera and correspondences (joint, or one beta-then-alpha step)."""
        m = self.model
        As = fitting.design(J, rows_s, rho, w_all)
        Ae = fitting.design(J, rows_e, rho, w_all)
        r = fitting.whiten(x_all - u0, rho, w_all)
        if self.coefficients == "joint":
            return fitting.solve_joint(As, Ae, r + As @ alpha + Ae @ beta, self.shape_lambda, self.expression_lambda,
                                       *prior, lower=m.expression_lower, upper=m.expression_upper)
        if m.num_expression:
            new_beta = fitting.solve_regularised(Ae, r + Ae @ beta, self.expression_lambda,
                                                 lower=m.expression_lower, upper=m.expression_upper)
            r = r - Ae @ (new_beta - beta)  # exact for orthographic, first order for perspective
            beta = new_beta
        if self.num_shape:
            alpha = fitting.solve_regularised(As, r + As @ alpha, self.shape_lambda, *prior)
        return alpha, beta

    def _with_outline(self, fv, fw, x_fixed, w_fixed, x_out, w_out, out_side, alpha, beta, R, t, s):
        """Correspondences with the outline landmarks added for the current shape and pose."""
        coef = np.r_[alpha, beta].astype(np.float32)
        Vm = (self.model.mean.reshape(-1) + self._full_basis @ coef).reshape(-1, 3).astype(np.float64)
        C, P = self._camera(Vm, R, t, s)
        perspective = self.projection == "perspective"
        # Occluders must be 20 mm nearer (the nose over the cheek, not the cheek's own grazing curve
        # within one cell); the splat grid is one mean edge length wide.
        px_per_mm = s if not perspective else 0.5 * (self.K[0, 0] + self.K[1, 1]) / float(np.median(C[:, 2]))
        tol = 20.0 * (s if not perspective else 1.0)
        cell = max(1.0, self._edge_mm * px_per_mm)
        vis = outline_corr.visible_candidates(self._geometry, C, P, perspective, tol, cell)
        verts = [fv]
        wts = [fw]
        xs = [x_fixed]
        ws = [w_fixed]
        for side in (0, 1):
            sel = out_side == side
            if not sel.any():
                continue
            band = self._bands[side]
            cand = band[vis[self._band_pos[side]]]
            if len(cand) == 0:
                continue
            v, b = outline_corr.outline_correspondences(
                x_out[sel], cand, P, C[:, 2] if perspective else None, self.outline_mode
            )
            verts.append(v)
            wts.append(b)
            xs.append(x_out[sel])
            ws.append(w_out[sel])
        return np.concatenate(verts), np.concatenate(wts), np.concatenate(xs), np.concatenate(ws)

    def _smooth(self, R, t, s, beta, now):
        rot = pose.rotation_log(R @ pose.FRONTAL.T)
        rot = self._filters["rot"](rot, now)
        # Translation filtered in model millimetres (orthographic t is in pixels: divide by s).
        unit = s if self.projection == "orthographic" else 1.0
        s_new = float(self._filters["s"](np.array([s]), now)[0])
        t = self._filters["t"](t / unit, now) * (s_new if self.projection == "orthographic" else 1.0)
        s = s_new
        if len(beta):
            beta = self._filters["beta"](beta, now)
        return pose.rodrigues(rot) @ pose.FRONTAL, t, s, beta

    # ------------------------------------------------------------------ dense
    def _fit_dense(self, pts, ids, w, finite, now) -> FitResult:
        m = self.model
        V = m.num_vertices
        idx = []
        vert = []
        for i, name in enumerate(ids):
            if finite[i] and name in self._names:
                idx.append(i)
                vert.append(self._names[name])
        idx = np.asarray(idx, int)
        vert = np.asarray(vert, int)
        if len(np.unique(vert)) < max(self.min_landmarks, V // 2):
            raise FitError(
                f"dense fit needs at least {max(self.min_landmarks, V // 2)} of the {V} mesh points, got {len(np.unique(vert))}"
            )
        obs = np.zeros((V, 3))
        have = np.zeros(V, bool)
        obs[vert, :2] = pts[idx, :2]
        obs[vert, 2] = pts[idx, 2] if pts.shape[1] == 3 else 0.0
        have[vert] = True
        wv = np.zeros(V)
        wv[vert] = w[idx]
        # Observation in a right-handed "pixel space" aligned with the camera (x right, y down,
        # z away): the network's relative depth grows away from the camera like camera z.
        if not np.isfinite(obs[have]).all():
            raise FitError("dense points contain NaN or infinite depth")
        spread = np.linalg.svd(obs[have, :2] - obs[have, :2].mean(0), compute_uv=False)
        if spread[1] < 1e-3 * max(spread[0], 1e-12):
            raise FitError("dense points are collinear (or coincide): the pose is undetermined")
        if pts.shape[1] == 2:
            raise FitError("dense mode needs (N, 3) points with the network's relative depth")

        learned_now = False
        if self._neutral_count == 0 and "canonical" not in self.model.source and have.all():
            # No reference yet: this frame's own shape is the first estimate of the neutral.
            learned_now = self._learn_neutral(obs, None)
        ref = self.model.mean.astype(np.float64)
        # Robust weighted similarity: vertices moved by expression are down-weighted
        # (Geman-McClure on the residual, scale 3 mm) over a few re-weighting rounds.
        wr = wv * have
        for _ in range(4):
            s, R, t = pose.similarity_procrustes(ref[have], obs[have], wr[have])
            res = np.linalg.norm((s * ref @ R.T + t) - obs, axis=1) / s  # mm
            wr = wv * have / (1 + (res / 3.0) ** 2) ** 2
        posed_ref = s * ref @ R.T + t
        # Non-rigid deviation of the observation from the posed reference (expression + reference error).
        residual = float(np.sqrt(((posed_ref[have, :2] - obs[have, :2]) ** 2).sum(1).mean()))
        if not learned_now and have.all():
            self._learn_neutral(obs, (s, R, t))
        # The fitted shape in model space: the observation itself, the reference where unobserved.
        local = ref.copy()
        local[have] = (obs[have] - t) @ R / s
        if self.smoothing:
            R, t, s, _ = self._smooth(R, t, s, np.zeros(0), now)
            local = self._filters["dense"](local, now)
        cam_px = s * local @ R.T + t  # camera space in pixel scale (x, y pixels; z relative depth)
        if self.projection == "orthographic":
            vertices, proj = cam_px, cam_px[:, :2]
            R_out, t_out, s_out = R, t, s
        else:
            # Weak perspective made metric: s px/mm at the reference depth Z0 = f / s; each point's
            # depth is offset by its relative depth / s (mm), and back-projected through K.
            f = 0.5 * (self.K[0, 0] + self.K[1, 1])
            Z0 = f / s
            Z = Z0 + (cam_px[:, 2] - t[2]) / s
            X = (cam_px[:, 0] - self.K[0, 2]) * Z / self.K[0, 0]
            Y = (cam_px[:, 1] - self.K[1, 2]) * Z / self.K[1, 1]
            vertices = np.column_stack([X, Y, Z])
            t_out = np.array([(t[0] - self.K[0, 2]) * Z0 / self.K[0, 0], (t[1] - self.K[1, 2]) * Z0 / self.K[1, 1], Z0])
            R_out, s_out = R, 1.0
            proj = project(vertices, self.K)
        self._pose = (R, t, s)
        return FitResult(
            vertices=vertices.astype(np.float32), projected=proj.astype(np.float32), R=R_out, t=t_out,
            scale=float(s_out), alpha=np.zeros(0, np.float32), beta=np.zeros(0, np.float32),
            residual_px=residual, projection=self.projection, K=self.K,
            model_vertices=local.astype(np.float32), landmarks_used=int(have.sum()),
        )

    def _learn_neutral(self, obs, sim) -> bool:
        """Running mean (model space) of the first ``neutral_frames`` frames' shapes; each frame is
        normalised (centred, eye-corner axis, 90 mm) and aligned to the current reference before it
        is averaged. Returns whether the reference changed."""
        if self._neutral_frozen:
            return False
        try:
            shape = normalise_facemesh_neutral(obs if sim is None else (obs - sim[2]) @ sim[1] / sim[0])
        except ValueError:
            return False
        if self._neutral_count:
            s2, R2, t2 = pose.similarity_procrustes(shape, self.model.mean)
            shape = s2 * shape @ R2.T + t2
        if self._neutral_sum is None:
            self._neutral_sum = np.zeros_like(shape, np.float64)
        self._neutral_sum += shape
        self._neutral_count += 1
        mean = normalise_facemesh_neutral(self._neutral_sum / self._neutral_count)
        base = self.model.source.split("; neutral learned")[0]
        self.model = self.model.with_mean(mean, source=f"{base}; neutral learned from {self._neutral_count} frames")
        self.neutral_version += 1
        if self._neutral_count >= self.neutral_frames:
            self._neutral_frozen = True
        return True
