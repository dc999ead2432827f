"""The sparse fitter: a morphable model with shape and expression bases (e.g. the Surrey Face
Model) fitted to named landmarks (e.g. the 68 iBUG points).

Per frame:

1. pose from the current shape at the landmark correspondences (scaled orthographic, or
   perspective with the intrinsics K; warm-started from the previous frame);
2. outline correspondences for the outline landmarks (:mod:`.outline`: visible outline
   candidates, ray-triangle point);
3. expression beta by bounded regularised least squares given alpha (:mod:`.fitting`);
4. shape alpha likewise given beta, with the identity evidence of earlier frames;

alternated ``iterations`` times (``tracking_iterations`` when warm-started), then a last pose
update. Identity alpha accumulates across frames (:class:`.fitting.IdentityAccumulator`) while
pose and beta follow each frame; the pose and beta of the result are smoothed over time
(:mod:`.pose_smoothing`).
"""

from __future__ import annotations

import numpy as np

from facesculpt.nodes.fitter import fitting
from facesculpt.nodes.fitter import outline as outline_corr
from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.nodes.fitter.detector_rotation import RIGID_IDS, DetectorRotation
from facesculpt.nodes.fitter.fit_camera import FitCamera
from facesculpt.nodes.fitter.fitter import Fitter
from facesculpt.nodes.fitter.model import MorphableModel
from facesculpt.nodes.fitter.result import FitError, FitResult

#: Kept frames whose landmark-only rotation is fitted again per frame once the identity has
#: settled (``rotation_prior_relearn_frames``): the one-time work spread over a few frames.
RELEARN_PER_FRAME = 8


class SparseFitter(Fitter):
    """Fits ``model`` (with bases, not dense) to named landmarks; see the module docstring."""

    def __init__(self, model: MorphableModel, config: FitterConfig, camera: FitCamera):
        super().__init__(model, config, camera)
        self.iterations = config.iterations
        self.tracking_iterations = (config.iterations if config.tracking_iterations is None
                                    else min(config.iterations, config.tracking_iterations))
        m = model
        S = m.num_shape if config.num_shape is None else min(config.num_shape, m.num_shape)
        self.num_shape = S
        # Bases pre-scaled by their standard deviations: a coefficient of 1 is one sigma.
        self._shape_basis = (m.shape_basis[:, :, :S] * m.shape_std[:S]).astype(np.float64)
        self._expr_basis = (m.expression_basis * m.expression_std).astype(np.float64)
        self._mean = m.mean.astype(np.float64)
        V = m.num_vertices
        self._full_basis = np.concatenate([self._shape_basis, self._expr_basis], axis=2).reshape(3 * V, -1).astype(np.float32)
        self._outline_side: dict[str, int] = {}
        for n in m.outline_landmarks_right:
            self._outline_side[n] = 0
        for n in m.outline_landmarks_left:
            self._outline_side[n] = 1
        self._bands: list[np.ndarray] = []
        self._geometry = None
        if len(m.outline_right) and len(m.outline_left):
            self._prepare_outline()
        # the model's calibration of the network's points (model mm from each landmark's vertex, weights)
        L = len(m.landmark_names)
        self._landmark_offset = dict(zip(m.landmark_names, m.landmark_offsets if len(m.landmark_offsets) else np.zeros((L, 3))))
        self._landmark_weight = dict(zip(m.landmark_names, m.landmark_weights if len(m.landmark_weights) else np.ones(L)))
        self._fixed_offsets = np.zeros((0, 3))
        self.identity = fitting.IdentityAccumulator(S, config.identity_decay, config.identity_max_frames)
        self.network_rotation = DetectorRotation(config.neutral_frames, gain=m.network_rotation_gain,
                                                 settle_frames=config.rotation_prior_settle_frames,
                                                 keep_frames=config.rotation_prior_relearn_frames
                                                 if config.accumulate_identity and S else 0)
        self.identity_moved_mm = float("nan")   # the identity's landmark points' move over the last frame
        self.reset()

    def _prepare_outline(self) -> None:
        """The outline candidate bands (without the nose) and their occlusion geometry."""
        m = self.model
        nose = outline_corr.nose_region(m.mean, self._names)
        self._bands = [outline_corr.outline_band(m.mean, m.outline_right, nose),
                       outline_corr.outline_band(m.mean, m.outline_left, nose)]
        cands = np.unique(np.r_[self._bands[0], self._bands[1]])
        self._geometry = outline_corr.OutlineGeometry(m.triangles, cands, m.num_vertices, transparent=nose)
        self._band_pos = [np.searchsorted(cands, b) for b in self._bands]
        edges = m.mean[m.triangles[:, [1, 2, 0]]] - m.mean[m.triangles]
        self._edge_mm = float(np.linalg.norm(edges, axis=2).mean())

    def reset(self) -> None:
        """Forget everything learned from earlier frames: warm start, identity, filters."""
        self.identity.reset()
        self.network_rotation.reset()
        self._relearn_alpha: np.ndarray | None = None   # the settled identity the kept frames are fitted with
        self._relearned: list = []
        self._alpha = np.zeros(self.num_shape)
        self._beta = np.zeros(self.model.num_expression)
        super().reset()

    @property
    def neutral(self) -> np.ndarray:
        """(V, 3) float32 the model mean plus the accumulated identity (and, refining by
        appearance, the refinement's mean shape change), model space (mm)."""
        alpha = self._alpha.astype(np.float32)   # a new array: the identity itself stays as it is
        change = self.refiner.shape_change
        if change is not None:
            alpha[:len(change)] += change.astype(np.float32)
        return self.model.instance(alpha)

    # ------------------------------------------------------------------ one frame
    def _fit(self, pts, ids, w, finite, now) -> FitResult:
        fixed_idx, fixed_vert, out_idx, out_side = self._select_landmarks(ids, finite)
        x_fixed = pts[fixed_idx, :2]
        w_fixed = w[fixed_idx] * np.array([self._landmark_weight[ids[i]] for i in fixed_idx])
        self._fixed_offsets = np.array([self._landmark_offset[ids[i]] for i in fixed_idx], np.float64).reshape(-1, 3)
        x_out, w_out = pts[out_idx, :2], w[out_idx] * self.config.outline_weight
        # Correspondences: fixed ones are (v, v, v) with weights (1, 0, 0).
        fv = np.repeat(np.asarray(fixed_vert, int)[:, None], 3, axis=1)
        fw = np.tile([1.0, 0.0, 0.0], (len(fixed_idx), 1))
        cv, cw, x_all, w_all = fv, fw, x_fixed, w_fixed
        self._outline_used = np.zeros(0, int)

        alpha, beta, init = self._alpha.copy(), self._beta.copy(), self._pose
        accumulate = self.config.accumulate_identity
        prior = (self.identity.H, self.identity.g) if (accumulate and not self.identity.empty) else (None, None)
        R_network = self._network_rotation(pts, ids, finite)
        R_prior = self.network_rotation.prior(R_network)
        # the pitch alone is held: the network's yaw follows a turn short of it, its roll no better
        held = None if R_prior is None else (R_prior, (self.config.rotation_prior_px, 0.0, 0.0))
        rows = self._rows(cv, cw)
        R, t, s = self.camera.estimate_pose(self._points(rows, alpha, beta), x_all, w_all, init, held)
        for _ in range(self.iterations if init is None else self.tracking_iterations):
            if len(out_idx):
                cv, cw, x_all, w_all = self._with_outline(fv, fw, x_fixed, w_fixed, x_out, w_out, out_side, alpha, beta, R, t, s)
                rows = self._rows(cv, cw)
            # With the correspondences fixed, pose and coefficients are alternated a few times:
            # cheap small solves that take most of the slow pose-shape coupling out of each iteration.
            for _ in range(self.config.inner_steps):
                C, u0 = self.camera.to_camera(self._points(rows, alpha, beta), R, t, s)
                J, rho = self.camera.linearisation(C, R, s)
                alpha, beta = self._solve_coefficients(J, rho, rows[1], rows[2], x_all, w_all, u0, alpha, beta, prior)
                R, t, s = self.camera.estimate_pose(self._points(rows, alpha, beta), x_all, w_all, (R, t, s), held)
        if R_network is not None:  # the offset is learned from the rotation the landmarks alone give
            free = R if held is None else self.camera.estimate_pose(self._points(rows, alpha, beta), x_all, w_all, (R, t, s))[0]
            record = (cv, cw, self._fixed_offsets, x_all, w_all, beta, (R, t, s))
            self.network_rotation.learn(R_network, free, record)
        residual = self._finish_frame(rows, x_all, w_all, alpha, beta, R, t, s)
        self._relearn_rotation_prior(rows, alpha)
        self._alpha, self._beta, self._pose = alpha, beta, (R, t, s)
        result = self._result(alpha, beta, R, t, s, now, residual)
        result.landmarks_used = len(fixed_idx) + len(out_idx)
        result.correspondences = (cv, cw)
        result.correspondence_ids = [ids[i] for i in fixed_idx] + [ids[out_idx[j]] for j in self._outline_used]
        return result

    def _relearn_rotation_prior(self, rows, alpha: np.ndarray) -> None:
        """Once the identity has settled (its landmark points moved at most
        ``rotation_prior_relearn_mm`` over the last frame, after the prior's reference frames; or
        the kept frames reach their cap), the kept frames' landmark-only rotations are fitted again
        with it, :data:`RELEARN_PER_FRAME` a frame, and the prior's offset is rebuilt from them
        (:meth:`.DetectorRotation.relearn`)."""
        net = self.network_rotation
        if net.keep_frames == 0 or net.relearned or not net.kept:
            return
        if self._relearn_alpha is None:
            moved = rows[1][: len(self._fixed_offsets)] @ (alpha - self._alpha)  # (L, 3) mm
            self.identity_moved_mm = float(np.sqrt((moved**2).sum(1).mean()))
            settled = (net.offsets_learned >= net.reference_frames
                       and self.identity_moved_mm <= self.config.rotation_prior_relearn_mm)
            if not settled and len(net.kept) < net.keep_frames:
                return
            self._relearn_alpha, self._relearned = alpha.copy(), []
        kept, done = net.kept, self._relearned
        if len(done) > len(kept):   # the prior started again meanwhile (a new reference): so does this
            self._relearn_alpha = None
            return
        done += [self._landmark_rotation(record, self._relearn_alpha)
                 for record in kept[len(done): len(done) + RELEARN_PER_FRAME]]
        if len(done) == len(kept):   # the frames kept meanwhile (below the cap) are fitted again too
            net.relearn(done)
            self._relearn_alpha = None

    def _landmark_rotation(self, record, alpha: np.ndarray) -> np.ndarray:
        """The rotation (3, 3) a kept frame's landmarks give alone with the identity ``alpha``: its
        expression and pose fitted again from its own (``inner_steps`` alternations, no prior;
        the frame's correspondences as they were)."""
        cv, cw, offsets, x, w, beta, (R, t, s) = record
        c, m = self.config, self.model
        rows = self._rows(cv, cw, offsets)
        for _ in range(c.inner_steps):
            if m.num_expression:
                C, u0 = self.camera.to_camera(self._points(rows, alpha, beta), R, t, s)
                J, rho = self.camera.linearisation(C, R, s)
                Ae = fitting.design(J, rows[2], rho, w)
                beta = self._solve_expression(Ae, fitting.whiten(x - u0, rho, w) + Ae @ beta)
            R, t, s = self.camera.estimate_pose(self._points(rows, alpha, beta), x, w, (R, t, s))
        return R

    def _network_rotation(self, pts: np.ndarray, ids: list[str], finite: np.ndarray):
        """The network's rotation (3, 3) of the head from its points' depth (:mod:`.detector_rotation`);
        None when the prior is off, the camera is orthographic or a point or its depth is missing."""
        if self.config.rotation_prior_px <= 0 or not self.camera.perspective or pts.shape[1] != 3:
            return None
        where = {name: i for i, name in enumerate(ids) if finite[i]}
        if any(name not in where for name in RIGID_IDS):
            return None
        return self.network_rotation.observe(pts[[where[name] for name in RIGID_IDS]])

    def _select_landmarks(self, ids: list[str], finite: np.ndarray):
        """The usable points: (indices, model vertices) of those with a fixed vertex, and
        (indices, side 0 right / 1 left) of the outline ones; FitError when too few are fixed."""
        fixed_idx, fixed_vert, out_idx, out_side = [], [], [], []
        for i, name in enumerate(ids):
            if not finite[i]:
                continue
            if name in self._outline_side:
                if self.config.outline != "off" and self._geometry is not None:
                    out_idx.append(i)
                    out_side.append(self._outline_side[name])
            elif name in self._names:
                fixed_idx.append(i)
                fixed_vert.append(self._names[name])
        if len(fixed_idx) < self.config.min_landmarks:
            known = sum(1 for i, n in enumerate(ids) if finite[i] and (n in self._names or n in self._outline_side))
            raise FitError(
                f"only {len(fixed_idx)} usable landmarks with fixed model vertices ({known} valid of {len(ids)} given; "
                f"at least {self.config.min_landmarks} are needed)"
            )
        return np.asarray(fixed_idx, int), fixed_vert, np.asarray(out_idx, int), np.asarray(out_side, int)

    def _rows(self, verts: np.ndarray, weights: np.ndarray, offsets: np.ndarray | None = None):
        """The correspondence points' mean (L, 3) and their rows of the shape and expression bases
        (the fixed landmarks, first, moved by the model's calibration offsets: ``offsets``, or this
        frame's)."""
        offsets = self._fixed_offsets if offsets is None else offsets
        base = fitting.correspondence_points(self._mean, verts, weights)
        base[:len(offsets)] += offsets
        rows_s = fitting.correspondence_rows(self._shape_basis, verts, weights)
        rows_e = fitting.correspondence_rows(self._expr_basis, verts, weights)
        return base, rows_s, rows_e

    @staticmethod
    def _points(rows, alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
        """The correspondence points (L, 3), model space, of shape ``alpha`` and expression ``beta``."""
        base, rows_s, rows_e = rows
        return base + rows_s @ alpha + rows_e @ beta

    def _finish_frame(self, rows, x_all, w_all, alpha, beta, R, t, s) -> float:
        """The frame's RMS landmark residual (px) at the final pose and coefficients; its
        identity evidence goes to the accumulator."""
        C, u0 = self.camera.to_camera(self._points(rows, alpha, beta), R, t, s)
        residual = float(np.sqrt(((u0 - x_all) ** 2).sum(1).mean()))
        if self.config.accumulate_identity and self.num_shape:
            J, rho = self.camera.linearisation(C, R, s)
            A = fitting.design(J, rows[1], rho, w_all)
            b = fitting.whiten(x_all - u0, rho, w_all) + A @ alpha
            self.identity.add(A, b)
        return residual

    def _result(self, alpha, beta, R, t, s, now, residual) -> FitResult:
        """The whole fitted mesh, posed (smoothed when asked) and projected; residual: RMS px."""
        if self.config.smoothing:
            if not self._rigid_smoothing_deferred:
                R, t, s = self.smoother.rigid(R, t, s, now)
            beta = self.smoother.expression(beta, now)
        coef = np.r_[alpha, beta].astype(np.float32)
        model_vertices = (self.model.mean.reshape(-1) + self._full_basis @ coef).reshape(-1, 3)
        Cv, proj = self.camera.to_camera(model_vertices.astype(np.float64), R, t, s)
        return FitResult(
            vertices=Cv.astype(np.float32), projected=proj.astype(np.float32), R=R, t=t, scale=float(s),
            alpha=alpha.astype(np.float32), beta=np.asarray(beta, np.float32), residual_px=residual,
            projection=self.projection, K=self.K, model_vertices=model_vertices.astype(np.float32),
        )

    def _solve_coefficients(self, J, rho, rows_s, rows_e, x_all, w_all, u0, alpha, beta, prior):
        """alpha, beta for fixed camera and correspondences (joint, or one beta-then-alpha step)."""
        m, c = self.model, self.config
        As = fitting.design(J, rows_s, rho, w_all)
        Ae = fitting.design(J, rows_e, rho, w_all)
        r = fitting.whiten(x_all - u0, rho, w_all)
        if c.coefficients == "joint":
            return fitting.solve_joint(As, Ae, r + As @ alpha + Ae @ beta, c.shape_lambda, c.expression_lambda,
                                       *prior, lower=m.expression_lower, upper=m.expression_upper)
        if m.num_expression:
            new_beta = self._solve_expression(Ae, r + Ae @ beta)
            r = r - Ae @ (new_beta - beta)  # exact for orthographic, first order for perspective
            beta = new_beta
        if self.num_shape:
            alpha = fitting.solve_regularised(As, r + As @ alpha, c.shape_lambda, *prior)
        return alpha, beta

    def _solve_expression(self, Ae: np.ndarray, r: np.ndarray) -> np.ndarray:
        """beta (E,) for the whitened design ``Ae`` and residual ``r`` (the current beta's share
        added back): the expression's regularisation and bounds."""
        m = self.model
        return fitting.solve_regularised(Ae, r, self.config.expression_lambda, lower=m.expression_lower,
                                         upper=m.expression_upper)

    def _with_outline(self, fv, fw, x_fixed, w_fixed, x_out, w_out, out_side, alpha, beta, R, t, s):
        """Correspondences with the outline landmarks added for the current shape and pose."""
        coef = np.r_[alpha, beta].astype(np.float32)
        Vm = (self.model.mean.reshape(-1) + self._full_basis @ coef).reshape(-1, 3).astype(np.float64)
        C, P = self.camera.to_camera(Vm, R, t, s)
        perspective = self.camera.perspective
        # Occluders must be 20 mm nearer (the nose over the cheek, not the cheek's own grazing curve
        # within one cell); the splat grid is one mean edge length wide.
        px_per_mm = s if not perspective else self.camera.focal_px / float(np.median(C[:, 2]))
        tol = 20.0 * (s if not perspective else 1.0)
        cell = max(1.0, self._edge_mm * px_per_mm)
        vis = outline_corr.visible_candidates(self._geometry, C, P, perspective, tol, cell)
        verts, wts, xs, ws = [fv], [fw], [x_fixed], [w_fixed]
        self._outline_used = np.zeros(0, int)  # which outline landmarks got correspondences, in order
        for side in (0, 1):
            sel = out_side == side
            if not sel.any():
                continue
            band = self._bands[side]
            cand = band[vis[self._band_pos[side]]]
            if len(cand) == 0:
                continue
            v, b = outline_corr.outline_correspondences(
                x_out[sel], cand, P, C[:, 2] if perspective else None, self.config.outline
            )
            verts.append(v)
            wts.append(b)
            xs.append(x_out[sel])
            ws.append(w_out[sel])
            self._outline_used = np.r_[self._outline_used, np.flatnonzero(sel)]
        return np.concatenate(verts), np.concatenate(wts), np.concatenate(xs), np.concatenate(ws)
