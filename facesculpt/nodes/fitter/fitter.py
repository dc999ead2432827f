"""A morphable model fitted to 2D landmarks, frame after frame (docs/architecture.md, "Stages":
stage 2). :func:`make_fitter` gives the fitter a model needs: :class:`.sparse_fitter.SparseFitter`
for a model with bases and named landmarks (the Surrey Face Model and 68 iBUG landmarks),
:class:`.dense_fitter.DenseFitter` for a dense one (``model.dense``: the built-in facemesh,
every vertex observed). Both are a :class:`Fitter`: one :meth:`Fitter.fit` per frame, options
from a :class:`.config.FitterConfig`, the camera a :class:`.fit_camera.FitCamera`.

What they share, here: reading the points, ids and weights of a frame; the frame clock (a
frame long after the previous one, or before it, starts cold); turning numerical failures into
:class:`.result.FitError`; the temporal smoothing of the result (:mod:`.pose_smoothing`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from facesculpt.geometry.projection import project
from facesculpt.nodes.fitter import pose
from facesculpt.nodes.fitter.appearance_refiner import AppearanceRefiner
from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.nodes.fitter.fit_camera import FitCamera
from facesculpt.nodes.fitter.model import MorphableModel
from facesculpt.nodes.fitter.pose_smoothing import PoseSmoother
from facesculpt.nodes.fitter.result import FitError, FitResult


class Fitter:
    """The frame loop of a fitter; subclasses fit one frame in :meth:`_fit`.

    model: the :class:`MorphableModel` (a dense fitter replaces it by one with the learned
    neutral as its mean); config: the options; camera: the camera of the frames.
    """

    def __init__(self, model: MorphableModel, config: FitterConfig, camera: FitCamera):
        self.model = model
        self.config = config
        self.camera = camera
        self._names = model.landmark_index()
        self.smoother = PoseSmoother(config.smooth_min_cutoff, config.smooth_beta, config.smooth_beta_mm,
                                     orthographic=not camera.perspective,
                                     beta_rotation=config.smooth_beta_rotation,
                                     predict_rotation=config.smooth_predict_rotation, predict_mm=config.smooth_predict_mm)
        self.neutral_version = 0  # changes of the neutral (dense: each learned frame)
        self._rigid_smoothing_deferred = False   # fit(): the subclass leaves the pose unsmoothed
        self.refiner = AppearanceRefiner(
            camera.K if camera.perspective else None, camera.projection, config.refine_after,
            config.refine or "appearance")
        self.depth_refiner = None  # made by the first frame with a depth image (.depth_fitting)

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget everything learned from earlier frames: warm start, filters (and the
        subclasses': identity, neutral)."""
        self._pose = None  # (R, t, s) of the previous frame
        self.refiner.reset()
        if self.depth_refiner is not None:
            self.depth_refiner.reset()
        self._last_time = None
        self._frame = 0
        self.smoother.reset()

    @property
    def projection(self) -> str:
        return self.camera.projection

    @property
    def K(self) -> np.ndarray | None:
        return self.camera.K

    @property
    def image_size(self) -> tuple[int, int]:
        return self.camera.image_size

    @property
    def frames_fitted(self) -> int:
        """Frames fitted since the last :meth:`reset`."""
        return self._frame

    @property
    def neutral(self) -> np.ndarray:
        """(V, 3) float32 the neutral model of this person, model space (mm)."""
        raise NotImplementedError

    @property
    def neutral_ready(self) -> bool:
        """The neutral is complete (dense: the learned reference is frozen)."""
        return True

    # ------------------------------------------------------------------ API
    def fit(self, points2d: np.ndarray, ids=None, weights: np.ndarray | None = None, stamp: float | None = None,
            corrections: dict | None = None, image: np.ndarray | None = None, depth=None) -> FitResult:
        """Fit one frame. points2d (N, 2) px (or (N, 3) with relative depth, used in dense mode);
        ids: the model landmark each point belongs to (iBUG numbers 1..68 for the SFM, vertex
        numbers 0..467 for facemesh; None for those two defaults); weights (N,) optional confidence;
        stamp: the frame time in seconds (for smoothing and warm start; default 1/30 s per call).
        Points with NaN, non-positive weight or an unknown id are ignored; raises :class:`FitError`
        when too few usable ones remain or they are degenerate. corrections: landmark id -> (x, y)
        px a person placed by hand (seed 002's interactive correction): that landmark is moved
        there and weighs ``config.correction_weight`` times a detected one, so a shape model moves
        the other points with it. image: the frame (H, W, 3) uint8 BGR or (H, W) grey; with
        ``config.refine`` ("appearance" or "pose") the fit is then refined on its pixels (:mod:`.appearance`).
        depth: the frame's aligned depth image (:class:`.depth_fitting.DepthImage`); with a
        perspective camera the fit is refined on it (:mod:`.depth_fitting`), without one nothing changes."""
        pts, ids, w, finite = self._parse(points2d, ids, weights)
        if corrections:
            pts, ids, w, finite = self._corrected(pts, ids, w, finite, corrections)
        now = float(stamp) if stamp is not None else (self._last_time + 1 / 30 if self._last_time is not None else 0.0)
        if self._last_time is not None and (now - self._last_time > self.config.warm_start_gap_s or now < self._last_time):
            self._pose = None  # too long since the last frame (or time went back): start cold
            self.smoother.reset()
            self.refiner.forget_frame()
        refining = self.config.refine is not None
        # the refinement measures the pose better: the pose is smoothed after it, not before (and
        # in the same units for a frame without an image, which is not refined)
        self._rigid_smoothing_deferred = refining and self.config.smoothing
        try:
            result = self._fit(pts, ids, w, finite, now)
        except pose.PoseError as exc:
            raise FitError(str(exc)) from None
        except np.linalg.LinAlgError as exc:
            raise FitError(f"the fit is numerically degenerate: {exc}") from None
        self._last_time = now
        self._frame += 1
        if depth is not None and self.camera.perspective:
            result = self._depth_refined(result, pts, ids, depth)
        if refining and image is not None:
            # the landmark fit goes along: the expression's landmark residual is its, not the refined pose's
            result = dataclasses.replace(self.refiner.refine(self.model, result, image), landmark_fit=result)
        if self._rigid_smoothing_deferred:
            result = self._smoothed_rigid(result, now)
        return result

    def _depth_refined(self, result: FitResult, pts: np.ndarray, ids: list[str], depth) -> FitResult:
        """``result`` refined on the aligned ``depth`` image (:mod:`.depth_fitting`)."""
        from .depth_fitting import DepthRefiner

        if self.depth_refiner is None or self.depth_refiner.model is not self.model:
            self.depth_refiner = DepthRefiner(self.model, len(result.alpha))
        return self.depth_refiner.refine(result, pts, result.correspondence_ids or ids, ids, depth, self.K)

    def fit_image(self, image: np.ndarray, init: FitResult, appearance_model) -> FitResult:
        """``init`` (this fitter's landmark fit of the photo ``image``, (H, W, 3) uint8 BGR) aligned
        by appearance against ``appearance_model`` (:class:`.appearance_model.AppearanceModel`):
        a 3D active appearance model fit (seed 004; :func:`.fit_image.fit_image`)."""
        from .fit_image import fit_image

        return fit_image(image, init, self.model, appearance_model, self.K if self.camera.perspective else None,
                         self.projection)

    def _smoothed_rigid(self, result: FitResult, now: float) -> FitResult:
        """``result`` moved from its head pose to the smoothed one (the subclass deferred that
        smoothing to after the refinement)."""
        R0, t0, s0 = np.asarray(result.R, np.float64), np.asarray(result.t, np.float64), float(result.scale)
        R, t, s = self.smoother.rigid(R0, t0, s0, now)
        V = (np.asarray(result.vertices, np.float64) - t0) @ ((s / s0) * R @ R0.T).T + t
        return dataclasses.replace(result, vertices=V.astype(np.float32), R=R, t=t, scale=float(s),
                                   projected=project(V, self.K, self.projection).astype(np.float32))

    def _fit(self, pts: np.ndarray, ids: list[str], w: np.ndarray, finite: np.ndarray, now: float) -> FitResult:
        """One frame: points (N, 2 or 3) float64 px, ids (N,) str, weights (N,), finite (N,) bool
        (the points to use), time ``now`` (s)."""
        raise NotImplementedError

    def _corrected(self, pts, ids, w, finite, corrections: dict):
        """The points with the corrected landmarks moved (or added) and weighted up."""
        pts, w, finite, ids = pts.copy(), w.copy(), finite.copy(), list(ids)
        where = {name: i for i, name in enumerate(ids)}
        for name, xy in corrections.items():
            xy = np.asarray(xy, np.float64).reshape(-1)
            if xy.shape != (2,) or not np.all(np.isfinite(xy)):
                raise FitError(f"the correction of landmark {name!r} must be 2 finite pixel coordinates, got {xy}")
            name = str(name)
            if name not in where:
                pts = np.vstack([pts, np.r_[xy, np.zeros(pts.shape[1] - 2)]])
                w, finite, ids = np.r_[w, 1.0], np.r_[finite, True], ids + [name]
                where[name] = len(ids) - 1
            i = where[name]
            pts[i, :2], w[i], finite[i] = xy, self.config.correction_weight, True
        return pts, ids, w, finite

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
