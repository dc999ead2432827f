"""The dense fitter: the built-in facemesh model (``model.dense``), every vertex observed.

The 468 network points (x, y px; z relative depth in pixel scale) observe every vertex. The pose
is a weighted, robustly re-weighted similarity Procrustes of the neutral reference onto the
points; the fitted mesh is the observation itself (in camera space: back-projected through K at
the pose's depth, or pixel scale under orthographic); the neutral reference of this person is
learned as the running mean, in model space, of the first ``neutral_frames`` frames
(:mod:`.neutral_learning`; then frozen; :attr:`DenseFitter.neutral_version` counts its changes).
"""

from __future__ import annotations

import numpy as np

from facesculpt.geometry.projection import project
from facesculpt.nodes.fitter import pose
from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.nodes.fitter.fit_camera import FitCamera
from facesculpt.nodes.fitter.fitter import Fitter
from facesculpt.nodes.fitter.model import MorphableModel
from facesculpt.nodes.fitter.neutral_learning import NeutralLearner
from facesculpt.nodes.fitter.result import FitError, FitResult

#: Scale (mm) of the Geman-McClure weight that down-weights vertices moved by expression in the pose.
ROBUST_SCALE_MM = 3.0
#: Re-weighting rounds of the robust similarity.
ROBUST_ROUNDS = 4


class DenseFitter(Fitter):
    """Fits a dense ``model`` (facemesh) to its observed vertices; see the module docstring."""

    def __init__(self, model: MorphableModel, config: FitterConfig, camera: FitCamera):
        super().__init__(model, config, camera)
        self.learner = NeutralLearner(config.neutral_frames)
        self.reset()

    def reset(self) -> None:
        """Forget everything learned from earlier frames: warm start, filters, neutral (the
        reference learned so far stays the model's mean until frames replace it)."""
        self.learner.reset()
        super().reset()

    @property
    def neutral(self) -> np.ndarray:
        """(V, 3) float32 the learned reference, model space (mm)."""
        return self.model.mean

    @property
    def neutral_ready(self) -> bool:
        """The learned neutral reference is complete (frozen)."""
        return self.learner.frozen

    # ------------------------------------------------------------------ one frame
    def _fit(self, pts, ids, w, finite, now) -> FitResult:
        obs, have, wv = self._observation(pts, ids, w, finite)
        learned_now = False
        if self.learner.count == 0 and have.all():
            # No reference yet: this frame's own shape is the first estimate of the neutral.
            learned_now = self._learn(obs, None)
        ref = self.model.mean.astype(np.float64)
        s, R, t = _robust_similarity(ref, obs, have, wv)
        posed_ref = s * ref @ R.T + t
        # Non-rigid deviation of the observation from the posed reference (expression + reference error).
        residual = float(np.sqrt(((posed_ref[have, :2] - obs[have, :2]) ** 2).sum(1).mean()))
        if not learned_now and have.all():
            self._learn(obs, (s, R, t))
        # The fitted shape in model space: the observation itself, the reference where unobserved.
        local = ref.copy()
        local[have] = (obs[have] - t) @ R / s
        if self.config.smoothing:
            frame_fit = (R, t, s, local)
            if not self._rigid_smoothing_deferred:
                R, t, s = self.smoother.rigid(R, t, s, now)
            local = self.smoother.shape(local, now)
        posed = self._posed(local, R, t, s)
        if self.config.smoothing and self.config.smooth_max_lag > 0:
            R, t, s, local, posed = self._within_lag(frame_fit, (R, t, s, local), posed)
        vertices, proj, t_out, s_out = posed
        self._pose = (R, t, s)
        return FitResult(
            vertices=vertices.astype(np.float32), projected=proj.astype(np.float32), R=R, t=t_out,
            scale=float(s_out), alpha=np.zeros(0, np.float32), beta=np.zeros(0, np.float32),
            residual_px=residual, projection=self.projection, K=self.K,
            model_vertices=local.astype(np.float32), landmarks_used=int(have.sum()),
        )

    def _within_lag(self, frame_fit: tuple, smoothed: tuple, smoothed_posed: tuple) -> tuple:
        """The ``smoothed`` (R, t, s, shape) drawn toward the frame's own ``frame_fit`` until its
        pixels lie within ``smooth_max_lag`` of the face's size of the frame's (mean over the
        vertices; the pose and shape blended, the rotation along its geodesic), with its
        :meth:`_posed` (``smoothed_posed``: the smoothed fit's); the filters go on from what is
        returned. A smoothed fit already within is returned as it is."""
        R0, t0, s0, local0 = frame_fit
        R1, t1, s1, local1 = smoothed
        px0 = self._posed(local0, R0, t0, s0)[1]
        lag = float(np.linalg.norm(smoothed_posed[1] - px0, axis=1).mean())
        side = px0.max(0) - px0.min(0)
        limit = self.config.smooth_max_lag * float(np.sqrt(max(side[0] * side[1], 0.0)))
        if lag <= limit:
            return (*smoothed, smoothed_posed)
        keep = limit / lag   # the share of the smoothing's departure from the frame that is kept
        R = R0 @ pose.rodrigues(keep * pose.rotation_log(R0.T @ R1))
        t, s, local = t0 + keep * (t1 - t0), s0 + keep * (s1 - s0), local0 + keep * (local1 - local0)
        if not self._rigid_smoothing_deferred:
            self.smoother.hold_rigid(R, t, s)
        self.smoother.hold_shape(local)
        return R, t, s, local, self._posed(local, R, t, s)

    def _observation(self, pts, ids, w, finite):
        """The observed vertices: positions (V, 3) in a right-handed "pixel space" aligned with
        the camera (x right, y down, z away: the network's relative depth grows away from the
        camera like camera z), which are observed (V,) bool, their weights (V,). FitError when
        fewer than half the mesh, non-finite depth, collinear points or no depth."""
        V = self.model.num_vertices
        idx, vert = [], []
        for i, name in enumerate(ids):
            if finite[i] and name in self._names:
                idx.append(i)
                vert.append(self._names[name])
        idx = np.asarray(idx, int)
        vert = np.asarray(vert, int)
        need = max(self.config.min_landmarks, V // 2)
        if len(np.unique(vert)) < need:
            raise FitError(f"dense fit needs at least {need} of the {V} mesh points, got {len(np.unique(vert))}")
        obs = np.zeros((V, 3))
        have = np.zeros(V, bool)
        obs[vert, :2] = pts[idx, :2]
        obs[vert, 2] = pts[idx, 2] if pts.shape[1] == 3 else 0.0
        have[vert] = True
        wv = np.zeros(V)
        wv[vert] = w[idx]
        if not np.isfinite(obs[have]).all():
            raise FitError("dense points contain NaN or infinite depth")
        spread = np.linalg.svd(obs[have, :2] - obs[have, :2].mean(0), compute_uv=False)
        if spread[1] < 1e-3 * max(spread[0], 1e-12):
            raise FitError("dense points are collinear (or coincide): the pose is undetermined")
        if pts.shape[1] == 2:
            raise FitError("dense mode needs (N, 3) points with the network's relative depth")
        return obs, have, wv

    def _learn(self, obs, similarity) -> bool:
        """Average this frame into the neutral reference; whether the reference changed."""
        model = self.learner.add(self.model, obs, similarity)
        if model is None:
            return False
        self.model = model
        self.neutral_version += 1
        return True

    def _posed(self, local, R, t, s):
        """The model-space shape ``local`` (V, 3) in camera space under the pose (s px/mm, R, t px):
        (vertices (V, 3), pixels (V, 2), t, scale) of the result."""
        cam_px = s * local @ R.T + t  # camera space in pixel scale (x, y pixels; z relative depth)
        if not self.camera.perspective:
            return cam_px, cam_px[:, :2], t, s
        # Weak perspective made metric: s px/mm at the reference depth Z0 = f / s; each point's
        # depth is offset by its relative depth / s (mm), and back-projected through K.
        K = self.K
        Z0 = self.camera.focal_px / s
        Z = Z0 + (cam_px[:, 2] - t[2]) / s
        X = (cam_px[:, 0] - K[0, 2]) * Z / K[0, 0]
        Y = (cam_px[:, 1] - K[1, 2]) * Z / K[1, 1]
        vertices = np.column_stack([X, Y, Z])
        t_out = np.array([(t[0] - K[0, 2]) * Z0 / K[0, 0], (t[1] - K[1, 2]) * Z0 / K[1, 1], Z0])
        return vertices, project(vertices, K), t_out, 1.0


def _robust_similarity(ref: np.ndarray, obs: np.ndarray, have: np.ndarray, weights: np.ndarray):
    """(s, R, t) mapping the reference (V, 3) mm onto the observed vertices (V, 3) px: weighted
    similarity Procrustes, vertices moved by expression down-weighted (Geman-McClure on the
    residual in mm) over a few re-weighting rounds."""
    wr = weights * have
    for _ in range(ROBUST_ROUNDS):
        s, R, t = pose.similarity_procrustes(ref[have], obs[have], wr[have])
        res = np.linalg.norm((s * ref @ R.T + t) - obs, axis=1) / s  # mm
        wr = weights * have / (1 + (res / ROBUST_SCALE_MM) ** 2) ** 2
    return s, R, t
