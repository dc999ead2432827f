"""What a fitter keeps to refine its landmark fits on the frames' pixels (issue 20), frame after frame.

Per person: the appearance template (:class:`.appearance.AppearanceTemplate`), the corners of
the last frame tied to the mesh (:mod:`.surface_features`) and that frame, the last refinements
(where the next ones start) and the mean shape change (:attr:`AppearanceRefiner.shape_change`,
which a sparse fitter adds to its learned neutral). With a shape basis, every SHAPE_EVERY-th frame
is first solved for pose and shape (a sample of the person's shape, averaged over frames); every
frame is solved for the pose alone for the mesh with the averaged shape, the one the output carries.
:meth:`AppearanceRefiner.refine` takes a frame's landmark fit, *before* its head pose is
smoothed, and returns it refined; the fitter smooths the refined pose afterwards, so the
smoothing filters the better measurement rather than the refinement adding unfiltered motion to
a smoothed fit.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from facesculpt.geometry.point_bounds import centroid
from facesculpt.geometry.projection import project
from facesculpt.geometry.vertex_normals import vertex_normals

from . import appearance
from .model import MorphableModel, basis_combination
from .result import FitResult
from .rigid_regions import has_rigid_regions, rigid_regions
from .surface_features import surface_features, track_features


class AppearanceRefiner:
    """AppearanceRefiner(K, projection, learn_frames, mode): ``K`` (3, 3) or None (orthographic),
    ``projection`` the fitter's; the first ``learn_frames`` frames only learn the appearance.
    ``mode`` "appearance": the pose and the leading shape components from every vertex the frame
    sees; "pose": the rigid pose alone, from the rigid regions (:mod:`.rigid_regions`), with a
    lighting gain and bias per region and the landmark prior weighed by the landmark fit's residual
    (:func:`.appearance.pose_prior_weight`); its corners are taken from those regions too."""

    def __init__(self, K: np.ndarray | None, projection: str, learn_frames: int, mode: str = "appearance"):
        self.K = K
        self.projection = projection
        self.learn_frames = int(learn_frames)
        self.mode = mode
        self._regions: tuple | None = None   # (the model, its (V,) rigid regions or None)
        self.reset()

    def reset(self) -> None:
        """Forget the person: the template, the mean shape change, and :meth:`forget_frame`."""
        self.template: appearance.AppearanceTemplate | None = None
        self.model_basis: np.ndarray | None = None   # the model's (V, 3, k) shape basis, mm: made once
        self.frames = 0
        self.forget_frame()
        # the shape change is the person's, not the frame's: it is averaged over frames
        self.shape_sum: np.ndarray | None = None
        self.shape_count = 0.0
        self.shape_applied: np.ndarray | None = None    # the mean, smoothed: what the fits are given
        self.shape_pending: np.ndarray | None = None    # the last sample, joining the mean in parts

    def forget_frame(self) -> None:
        """Forget the last frame (the next one is not its successor): its corners and refinement."""
        self.last_theta: np.ndarray | None = None        # the last pose refinement (6,)
        self.last_sample: np.ndarray | None = None       # the last pose-and-shape solve (6 + k,)
        self.previous: np.ndarray | None = None          # the last frame, (H, W) uint8
        self.features = None                             # its corners (SurfaceFeatures) or None
        self.kept = None                                 # (K, 2) px of them found in this frame
        self.speed_px = 0.0                              # their median motion into it, px

    def refine(self, model: MorphableModel, result: FitResult, image: np.ndarray) -> FitResult:
        """``result`` (a fit of ``model``) with its pose (and, with a shape basis, leading shape
        components) refined on ``image`` (H, W, 3) uint8 BGR or (H, W) grey once the appearance
        has been learned, then passed through the complementary filter; the refined fit teaches
        the template, and the frame's corners are kept for the next."""
        import cv2  # here: the fitter starts without OpenCV (a respawn's imports)
        grey8 = image if image.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2GRAY)
        grey8 = np.ascontiguousarray(grey8, np.uint8)
        grey = grey8.astype(np.float32)
        X = np.asarray(result.vertices, np.float64)
        if self.template is None or len(self.template.sum) != len(X) or \
                (self.previous is not None and self.previous.shape != grey8.shape):
            self.reset()
            self.template = appearance.AppearanceTemplate(len(X))
        perspective = self.K is not None
        normals = vertex_normals(X, model.triangles)
        R0 = np.asarray(result.R, np.float64)
        if self.frames >= self.learn_frames:
            result = self._refined(model, result, grey, X, normals)
        result = self._motion_filtered(result, grey8)
        X = np.asarray(result.vertices, np.float64)
        # the refinement moved the head rigidly (its shape change is slow): the normals turn with it
        normals = normals @ (np.asarray(result.R, np.float64) @ R0.T).T
        front = appearance.frontality(X, normals, perspective)
        projected = np.asarray(result.projected, np.float64)
        self.template.update(grey, projected, front)
        usable = front >= appearance.MIN_FRONTALITY
        regions = self.regions(model) if self.mode == "pose" else None
        if regions is not None:
            usable &= regions >= 0
        self.features = surface_features(grey8, projected, usable, kept=self.kept)
        self.kept = None
        self.previous = grey8
        self.frames += 1
        return result

    def _tracks(self, grey8: np.ndarray) -> tuple | None:
        """The last frame's corners found in this one, as :func:`.appearance.track_pose` takes them."""
        if self.features is None or self.previous is None:
            return None
        found, ok, error = track_features(self.previous, grey8, self.features)
        self.kept = found[ok]
        if ok.sum() < 10:
            return None
        f = self.features
        self.speed_px = float(np.median(np.linalg.norm(found[ok] - f.pixels[ok], axis=1)))
        return f.vertices[ok], f.weights[ok], f.offsets[ok], found[ok], error[ok]

    def _refined(self, model: MorphableModel, result: FitResult, grey: np.ndarray, X: np.ndarray,
                 normals: np.ndarray) -> FitResult:
        """``result`` refined against the template (:func:`.appearance.refine_pose`): with a shape
        basis, a first solve of the pose and the leading shape components (on every SHAPE_EVERY-th
        frame) gives a sample of the person's shape, whose running mean is applied; then the pose alone is
        solved for the mesh with that mean shape, so the output's pose fits the shape it is
        shown with (not the frame's noisier sample)."""
        front = appearance.frontality(X, normals, self.K is not None)
        w = self.template.confidence * appearance.frontal_weights(front)
        anchors = np.asarray(model.landmark_vertices, np.int64)
        if self.mode == "pose":
            return self._rigid_refined(model, result, grey, X, w, anchors)
        k = min(appearance.SHAPE_COMPONENTS, len(result.alpha), model.num_shape)
        if k:
            shape = None
            if self.last_sample is None or self.frames % appearance.SHAPE_EVERY == 0:
                self.model_basis, basis = shape_bases(model, result, k, self.model_basis)
                sample = appearance.refine_pose(grey, X, w, self.template.grey, self.K, anchors, basis=basis,
                                                start=self.last_sample, levels=appearance.SHAPE_LEVELS)
                self.last_sample, shape = sample.theta, sample.shape
            mean = appearance.Refinement(np.r_[np.zeros(6), self._mean_shape(shape, k)])
            result = refined_result(result, mean, self.model_basis, self.K, self.projection)
            X = np.asarray(result.vertices, np.float64)
        found = appearance.refine_pose(grey, X, w, self.template.grey, self.K, anchors, start=self.last_theta,
                                       levels=appearance.POSE_AFTER_SHAPE_LEVELS if k else None)
        self.last_theta = found.theta
        return refined_result(result, found, None, self.K, self.projection)

    def regions(self, model: MorphableModel) -> np.ndarray | None:
        """(V,) int8 ``model``'s rigid regions (:func:`.rigid_regions.rigid_regions` of its mean),
        kept per model; None for a model that does not name the landmarks they are made from."""
        if self._regions is None or self._regions[0] is not model:
            names = model.landmark_index()
            labels = rigid_regions(model.instance(), names) if has_rigid_regions(names) else None
            if labels is not None and (labels >= 0).sum() < 20:
                labels = None
            self._regions = (model, labels)
        return self._regions[1]

    def _rigid_refined(self, model: MorphableModel, result: FitResult, grey: np.ndarray, X: np.ndarray,
                       w: np.ndarray, anchors: np.ndarray) -> FitResult:
        """``result``'s rigid pose refined against the template on the rigid regions alone, a
        lighting gain and bias per region (the whole face where the model has no regions)."""
        regions = self.regions(model)
        if regions is not None:
            w = w * np.where(regions >= 0, 1.0, appearance.OUTSIDE_RIGID_WEIGHT)
            regions = np.where(regions >= 0, regions, regions.max() + 1)
        found = appearance.refine_pose(grey, X, w, self.template.grey, self.K, anchors, start=self.last_theta,
                                       prior_weight=appearance.pose_prior_weight(result.residual_px),
                                       levels=appearance.POSE_LEVELS, regions=regions)
        self.last_theta = found.theta
        return refined_result(result, found, None, self.K, self.projection)

    @property
    def shape_change(self) -> np.ndarray | None:
        """(k,) the person's shape change that the refined fits carry (standard deviations of the
        model's leading shape components): the mean of the frames' samples, smoothed over
        SHAPE_SMOOTHING_FRAMES; None before any."""
        return self.shape_applied

    def _mean_shape(self, shape: np.ndarray | None, k: int) -> np.ndarray:
        """The (k,) shape change to apply in this frame, given its sample ``shape`` (k,) (None: not
        sampled in this frame): the running mean of the samples (the oldest fading once those of
        SHAPE_FRAMES frames are held), each sample joining it in equal parts over the SHAPE_EVERY
        frames until the next (all at once, the mean would step every few frames and the face
        wobble at that rhythm), followed smoothly frame by frame (each sample moves the mean by
        its share, a visible wobble on a still face)."""
        if self.shape_sum is None or len(self.shape_sum) != k:
            self.shape_sum, self.shape_count, self.shape_applied = np.zeros(k), 0.0, np.zeros(k)
            self.shape_pending = None
        if shape is not None:
            self.shape_pending = np.asarray(shape, np.float64)
        if self.shape_pending is None:
            return self.shape_applied
        part = 1.0 / appearance.SHAPE_EVERY
        keep = min(1.0, appearance.SHAPE_FRAMES / appearance.SHAPE_EVERY / (self.shape_count + part))
        self.shape_sum = (self.shape_sum + part * self.shape_pending) * keep
        self.shape_count = (self.shape_count + part) * keep
        mean = self.shape_sum / self.shape_count
        self.shape_applied = self.shape_applied + (mean - self.shape_applied) / appearance.SHAPE_SMOOTHING_FRAMES
        return self.shape_applied

    def _motion_filtered(self, result: FitResult, grey8: np.ndarray) -> FitResult:
        """``result`` moved most of the way to where the corners tracked from the last frame put
        the face: a complementary filter, the tracked motion (precise from frame to frame) for
        the fast part and this frame's fit (BLEND of it per frame) for the slow part, so neither
        its noise nor a smoothing lag reaches the output."""
        tracks = self._tracks(grey8)
        if tracks is None:
            return result
        toward = appearance.track_pose(np.asarray(result.vertices, np.float64), self.K, tracks, steps=2)
        toward = appearance.Refinement((1.0 - appearance.blend(self.speed_px)) * toward.theta)
        return refined_result(result, toward, None, self.K, self.projection)


def shape_bases(model: MorphableModel, result: FitResult, k: int,
                model_basis: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The displacement of each vertex per standard deviation of ``model``'s k leading shape
    components: (V, 3, k) in model space (mm; ``model_basis`` when given, e.g. kept from an
    earlier frame), and (V, 3, k) in ``result``'s camera space (its scale and rotation; None when
    k is 0)."""
    if model_basis is None or model_basis.shape[2] != k:
        model_basis = model.shape_basis[:, :, :k].astype(np.float64) * model.shape_std[:k]
    basis = (result.scale * np.asarray(result.R, np.float64)) @ model_basis if k else None
    return model_basis, basis


def refined_result(result: FitResult, found: appearance.Refinement, model_basis: np.ndarray | None,
                   K: np.ndarray | None, projection: str) -> FitResult:
    """``result`` with ``found`` applied: its shape change along ``model_basis`` (V, 3, k) model space,
    mm (as :func:`shape_bases` gives it; the camera-space change is the model-space one turned and
    scaled by ``result``'s pose), then its rigid motion about ``result``'s centroid; pixels by ``K``
    and ``projection``."""
    X = np.asarray(result.vertices, np.float64)
    k = len(found.shape)
    model_vertices = np.asarray(result.model_vertices, np.float64)
    pose = found
    if k:
        change = basis_combination(model_basis, found.shape)             # (V, 3) model space, mm
        model_vertices = model_vertices + change
        # the camera-space change as a basis of one component at 1, so the rotation stays about
        # the centroid of ``result``'s vertices
        camera = result.scale * change @ np.asarray(result.R, np.float64).T
        pose = appearance.Refinement(np.r_[found.theta[:6], 1.0])
    c = centroid(X)
    X = pose.apply(X, camera[:, :, None] if k else None)
    alpha = np.asarray(result.alpha, np.float32).copy()
    alpha[:k] += found.shape.astype(np.float32)
    return dataclasses.replace(
        result, vertices=X.astype(np.float32), projected=project(X, K, projection).astype(np.float32),
        R=found.R @ np.asarray(result.R), t=found.R @ (np.asarray(result.t) - c) + c + found.t, alpha=alpha,
        model_vertices=model_vertices.astype(np.float32))
