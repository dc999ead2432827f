"""Photometric refinement of a landmark fit (issue 20, seeds 003 and 004): analysis by synthesis.

The landmark fit uses 68 (or 468) points; this step uses the face's pixels. An appearance
template (:class:`AppearanceTemplate`: per vertex, the grey level of the person's skin there, learned
from earlier frames where the frame saw that vertex frontally: a 3D AAM's mean texture in the
model's vertex space) is compared with the frame at the projected vertices, and the head's pose
(a small rotation about the mesh's centroid and a translation, camera space) and, given a shape
basis, the leading shape components are moved to reduce the difference by Gauss-Newton (:func:`refine_pose`): image gradients at the projected vertices
times the projection's Jacobian (the optical-flow constraint of seed 003), on a coarse-to-fine
pyramid of the frame, with the lighting's gain and bias solved each step, Huber weights (a hand,
hair or a highlight that does not match the template weighs less) and a prior that keeps the
landmark vertices near where the landmark fit put them, so it cannot drift; each frame starts
from the last frame's correction and is held near it.

:func:`track_pose` is the rigid motion that corners tracked from the last frame show
(:mod:`.surface_features`): the fast part of the complementary filter in :mod:`.appearance_refiner`.

Arrays in, arrays out: the fitter's :class:`.appearance_refiner.AppearanceRefiner` keeps the template.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesculpt.geometry.point_bounds import centroid, point_bounds
from facesculpt.geometry.projection import project

from .model import basis_combination
from .pose import projection_jacobian, rodrigues, skew

#: Image scales of the pyramid, coarse to fine, and Gauss-Newton steps at each.
LEVELS = (0.5, 1.0)
STEPS = 2
#: The pyramid scales of the two solves of :mod:`.appearance_refiner` with a shape basis: the
#: pose and shape one (whose shape sample joins the person's mean), then the pose-only one, which
#: starts close enough not to need the coarse level.
SHAPE_LEVELS = (0.5, 1.0)
POSE_AFTER_SHAPE_LEVELS = (1.0,)
#: The prior (the landmark vertices staying where the landmark fit put them): moving every landmark
#: vertex by 1 px costs as much as a photometric residual of sqrt(PRIOR_WEIGHT) grey levels at every
#: compared vertex.
PRIOR_WEIGHT = 0.1
#: A shape component's change by one standard deviation costs as much as a photometric residual of
#: sqrt(SHAPE_WEIGHT) grey levels at every compared vertex.
SHAPE_WEIGHT = 0.02
#: Moving every landmark vertex 1 px from where the last frame's refinement would put it costs as
#: much as a photometric residual of sqrt(TEMPORAL_WEIGHT) grey levels at every compared vertex.
TEMPORAL_WEIGHT = 1.0
#: Huber threshold of a tracked corner's distance, px (:func:`track_pose`).
TRACK_HUBER_PX = 1.0
#: ... and a track's forward-backward miss (px) at which it counts half (:func:`track_pose`).
TRACK_ERROR_PX = 0.1
#: The complementary filter (:func:`track_pose`, :mod:`.appearance_refiner`): each frame the
#: face follows the corners tracked from the last frame, and moves this share of the way back
#: to the frame's own fit.
BLEND = 0.1
#: ... rising to BLEND_MOVING while the tracked corners move MOVING_PX px a frame or more (the
#: ties of corners to the mesh drift as the head turns; a still face keeps the low blend).
BLEND_MOVING = 0.4
MOVING_PX = 2.0
#: The rigid pose refinement (``refine="pose"``, :mod:`.rigid_regions`): its pyramid's scales,
#: and its landmark prior, PRIOR_WEIGHT's meaning for a landmark fit whose RMS residual is
#: PRIOR_RESIDUAL_PX, growing as 1 / residual^2 for a closer one (at most PRIOR_MAX_GAIN times).
POSE_LEVELS = (0.25, 0.5, 1.0)
PRIOR_RESIDUAL_PX = 2.0
PRIOR_MAX_GAIN = 4.0
#: ... and the weight of a vertex outside the rigid regions (the mouth, the eyes, the jaw: a lighting
#: gain and bias of their own), relative to one inside them (0: the rigid regions alone).
OUTSIDE_RIGID_WEIGHT = 0.0
#: Shape components the refinement may change (the leading ones; 0: pose only).
SHAPE_COMPONENTS = 20
#: The refined shape change applied is the mean of the samples of the last this many frames (the
#: person's shape), followed by an exponential average over SHAPE_SMOOTHING_FRAMES frames.
SHAPE_FRAMES = 100
SHAPE_SMOOTHING_FRAMES = 5.0
#: The shape is sampled (the pose-and-shape solve) on every this-many-th frame only: the person's
#: shape does not change from frame to frame, and its samples are averaged anyway.
SHAPE_EVERY = 4
#: With an appearance model as the template (its mean and components), a component's mix of
#: one grey level costs as much as a photometric residual of sqrt(COMPONENT_RIDGE) grey levels at
#: every compared vertex.
COMPONENT_RIDGE = 0.1
#: At most this many vertices are compared (every n-th of those with a weight).
MAX_VERTICES = 1000
#: The frame is cropped to the face's box grown by this share of its sides.
CROP_MARGIN = 0.15
#: Huber threshold of the photometric residual, grey levels.
HUBER = 12.0
#: Vertices the frame sees less frontally than this (cosine) are neither learned nor compared.
MIN_FRONTALITY = 0.35
#: The template's confidence (summed weight) at which a vertex counts fully.
FULL_CONFIDENCE = 3.0


def frontality(vertices: np.ndarray, normals: np.ndarray, perspective: bool) -> np.ndarray:
    """(V,) cosine between each vertex normal and its ray to the camera (at the origin in
    perspective, along -z in orthographic), the sign chosen so the face is seen from its front."""
    X = np.asarray(vertices, np.float64)
    to_cam = -X / np.maximum(np.linalg.norm(X, axis=1, keepdims=True), 1e-9) if perspective else \
        np.broadcast_to([0.0, 0.0, -1.0], X.shape)
    cos = np.einsum("ij,ij->i", normals, to_cam)
    return -cos if cos.sum() < 0 else cos


def pose_prior_weight(residual_px: float) -> float:
    """The rigid refinement's landmark prior weight (PRIOR_WEIGHT's meaning) for a landmark fit
    whose RMS residual is ``residual_px`` px: the closer the landmarks agree with the fit, the
    more the pose is held where they put it."""
    gain = (PRIOR_RESIDUAL_PX / max(float(residual_px), 1e-6)) ** 2 if np.isfinite(residual_px) else 1.0
    return PRIOR_WEIGHT * min(PRIOR_MAX_GAIN, gain)


def blend(speed_px: float) -> float:
    """The complementary filter's share of the way back to the frame's own fit (see BLEND) when
    the tracked corners moved ``speed_px`` px since the last frame (their median)."""
    return BLEND + (BLEND_MOVING - BLEND) * min(1.0, max(0.0, speed_px / MOVING_PX))


def frontal_weights(front: np.ndarray) -> np.ndarray:
    """(V,) in [0, 1]: each vertex's weight in a photometric match from its :func:`frontality`
    ``front`` (V,), rising from 0 at MIN_FRONTALITY to 1 facing the camera."""
    return np.clip((front - MIN_FRONTALITY) / (1 - MIN_FRONTALITY), 0, 1)


class AppearanceTemplate:
    """AppearanceTemplate(n_vertices): the per-vertex grey level (:attr:`grey`) and confidence
    (:attr:`confidence`, summed weights, capped) of one person, learned by :meth:`update`."""

    def __init__(self, n_vertices: int, max_weight: float = 30.0):
        self.sum = np.zeros(int(n_vertices))
        self.weight = np.zeros(int(n_vertices))
        self.max_weight = float(max_weight)

    @property
    def grey(self) -> np.ndarray:
        return self.sum / np.maximum(self.weight, 1e-9)

    @property
    def confidence(self) -> np.ndarray:
        """(V,) in [0, 1]: how much each vertex's grey level is to be trusted."""
        return np.minimum(self.weight / FULL_CONFIDENCE, 1.0)

    def update(self, grey: np.ndarray, pixels: np.ndarray, front: np.ndarray) -> None:
        """Take the frame ``grey`` (H, W) float32 at the vertices' ``pixels`` (V, 2) with weight
        ``front`` (V,) frontality (nothing below MIN_FRONTALITY); the oldest samples fade once a
        vertex holds ``max_weight``."""
        values, inside = sample(grey, pixels)
        w = np.where(inside & (front >= MIN_FRONTALITY), front * front, 0.0)
        keep = np.minimum(1.0, self.max_weight / np.maximum(self.weight + w, 1e-9))
        self.sum = (self.sum + w * values) * keep
        self.weight = (self.weight + w) * keep


def sample(image: np.ndarray, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear values of ``image`` (H, W) or (H, W, C) float32 at ``pixels`` (N, 2): (N,) or
    (N, C) float64, and which of them lie inside it (N,) bool."""
    import cv2  # here: the fitter starts without OpenCV (a respawn's imports)
    h, w = image.shape[:2]
    p = np.asarray(pixels, np.float32).reshape(1, -1, 2)
    values = cv2.remap(image, p[..., 0], p[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    inside = (p[0, :, 0] >= 1) & (p[0, :, 1] >= 1) & (p[0, :, 0] < w - 2) & (p[0, :, 1] < h - 2)
    return values.reshape(len(inside), *image.shape[2:]).astype(np.float64), inside


def _projection_jacobian(X: np.ndarray, K: np.ndarray | None) -> np.ndarray:
    """(N, 2, 3) d pixel / d camera point: :func:`.pose.projection_jacobian`, or in orthographic
    (``K`` None) the first two coordinates."""
    if K is not None:
        return projection_jacobian(X, K)
    J = np.zeros((len(X), 2, 3))
    J[:, 0, 0] = J[:, 1, 1] = 1.0
    return J


@dataclass
class Refinement:
    """What :func:`refine_pose` found, ``theta`` (6 + k,): a rotation vector (rad), a translation
    (camera units) and the change of k shape coefficients (standard deviations; none without a
    basis). The refined vertices are ``((vertices + basis @ shape) - c) @ R.T + c + t`` with c the
    given vertices' centroid (:meth:`apply`); ``theta`` is also where the next frame starts."""

    theta: np.ndarray

    @property
    def R(self) -> np.ndarray:
        return rodrigues(self.theta[:3])

    @property
    def t(self) -> np.ndarray:
        return self.theta[3:6]

    @property
    def shape(self) -> np.ndarray:
        return self.theta[6:]

    def apply(self, vertices: np.ndarray, basis: np.ndarray | None = None) -> np.ndarray:
        """(V, 3) float64: ``vertices`` refined (``basis`` (V, 3, k) as given to :func:`refine_pose`)."""
        X = np.asarray(vertices, np.float64)
        return _moved(X, centroid(X), self.theta, None if basis is None else np.asarray(basis, np.float64))


def _moved(X: np.ndarray, centre: np.ndarray, theta: np.ndarray, basis: np.ndarray | None) -> np.ndarray:
    if basis is not None and len(theta) > 6:
        X = X + basis_combination(basis, theta[6:])
    return (X - centre) @ rodrigues(theta[:3]).T + centre + theta[3:6]


def _jacobian(Xm: np.ndarray, centre: np.ndarray, theta: np.ndarray, basis: np.ndarray | None,
              K: np.ndarray | None) -> np.ndarray:
    """(N, 2, 6 + k) d pixel / d (rotation, translation, shape) at the moved points ``Xm`` (N, 3)."""
    dX = [-skew(Xm - centre), np.broadcast_to(np.eye(3), (len(Xm), 3, 3))]
    if basis is not None:
        dX.append(np.einsum("ij,njk->nik", rodrigues(theta[:3]), basis))
    return np.einsum("nkj,nji->nki", _projection_jacobian(Xm, K), np.concatenate(dX, axis=2))


def _image_jacobian(grad: np.ndarray, Xm: np.ndarray, centre: np.ndarray, theta: np.ndarray,
                    basis: np.ndarray | None, K: np.ndarray | None) -> np.ndarray:
    """(N, 6 + k) d grey level / d (rotation, translation, shape): the image gradients ``grad``
    (N, 2) through :func:`_jacobian`, contracted first (a row times a cross-product matrix is a
    cross product) so no (N, 2, 6 + k) array is formed."""
    g = np.einsum("nk,nkj->nj", grad, _projection_jacobian(Xm, K))      # (N, 3): d grey / d point
    parts = [np.cross(Xm - centre, g), g]
    if basis is not None:
        parts.append(np.einsum("nj,njk->nk", g @ rodrigues(theta[:3]), basis))
    return np.concatenate(parts, axis=1)


def _pixel_term(X: np.ndarray, centre: np.ndarray, theta: np.ndarray, basis: np.ndarray | None,
                K: np.ndarray | None, vertices: np.ndarray, mix: np.ndarray, targets: np.ndarray,
                huber_px: float | None = None, point_weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(H (n, n), g (n,)) of sum |mix-weighted pixels of ``vertices`` - targets|^2 over points:
    vertices (P, m) int, mix (P, m) weights, targets (P, 2) px; Huber weights beyond ``huber_px``;
    each point's term times ``point_weights`` (P,) when given."""
    flat = vertices.reshape(-1)
    B = None if basis is None else basis[flat]
    Xm = _moved(X[flat], centre, theta, B)
    P, m = vertices.shape
    px = project(Xm, K, "perspective" if K is not None else "orthographic").reshape(P, m, 2)
    J = np.einsum("pk,pkcn->pcn", mix, _jacobian(Xm, centre, theta, B, K).reshape(P, m, 2, -1))
    r = np.einsum("pk,pkc->pc", mix, px) - targets
    w = np.ones(P)
    if huber_px is not None:
        d = np.linalg.norm(r, axis=1)
        w = np.where(d <= huber_px, 1.0, huber_px / np.maximum(d, 1e-9))
    if point_weights is not None:
        w = w * point_weights
    J = J.reshape(2 * P, -1)
    w = np.repeat(w, 2)
    return J.T @ (J * w[:, None]), J.T @ (w * r.reshape(-1))


def _pyramid_level(grey: np.ndarray, scale: float) -> np.ndarray:
    """(h, w, 3) float32: ``grey`` (H, W) float32 resized by ``scale`` and smoothed, with its x and
    y gradients (grey levels per pixel of the level) as the second and third channels, so that one
    lookup gives all three."""
    import cv2  # here: the fitter starts without OpenCV (a respawn's imports)
    small = cv2.GaussianBlur(cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA), (0, 0), 1.0)
    return cv2.merge([small, cv2.Sobel(small, cv2.CV_32F, 1, 0, ksize=3) / 8.0,
                      cv2.Sobel(small, cv2.CV_32F, 0, 1, ksize=3) / 8.0])


def lighting_basis(template: np.ndarray, regions: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The lighting's linear model of the frame's grey levels at n compared vertices: (A (n, m),
    ridged (m,) bool: the columns held near 0). template: (n,) grey levels or (n, 1 + c) an
    appearance model's mean and components; regions: (n,) int, a gain (times the mean) and a bias
    for each region, or None: one pair for all; then the c components, ridged."""
    t = np.asarray(template, np.float64).reshape(len(template), -1)
    groups = [np.ones(len(t), bool)] if regions is None else [regions == r for r in np.unique(regions)]
    columns = [c for g in groups for c in (t[:, 0] * g, g.astype(np.float64))]
    ridged = np.r_[np.zeros(len(columns), bool), np.ones(t.shape[1] - 1, bool)]
    return np.column_stack(columns + [t[:, 1:]]), ridged


def refine_pose(grey: np.ndarray, vertices: np.ndarray, weights: np.ndarray, template: np.ndarray,
                K: np.ndarray | None, anchors: np.ndarray, prior_weight: float | None = None,
                basis: np.ndarray | None = None, shape_weight: float | None = None,
                start: np.ndarray | None = None, temporal_weight: float | None = None,
                levels: tuple[float, ...] | None = None, regions: np.ndarray | None = None) -> Refinement:
    """The rigid motion (and, with a ``basis``, shape change) that best matches the frame to the template.

    grey: (H, W) float32 the frame's grey levels; vertices: (V, 3) float64 the landmark fit's
    camera-space mesh (mm with ``K`` (3, 3), else orthographic pixel units); weights: (V,) each
    vertex's weight (template confidence x frontality in this frame; 0: not compared); template:
    (V,) grey levels, or (V, 1 + c) an appearance model's mean and components (their mix is solved
    each step with the lighting, held near the mean by COMPONENT_RIDGE); anchors: (L,) int the vertices of the landmarks (the prior keeps them where
    they are, with ``prior_weight``: PRIOR_WEIGHT's meaning); basis: (V, 3, k) camera-space
    displacement of each vertex per standard deviation of k shape components (None: pose only),
    whose change costs ``shape_weight`` (SHAPE_WEIGHT's meaning); start: (6 + k,) the last frame's
    ``theta``, where the search starts and which the landmark vertices' pixels are held near with
    ``temporal_weight`` (TEMPORAL_WEIGHT's meaning); levels: the pyramid's scales (LEVELS);
    regions: (V,) int each vertex's region (:mod:`.rigid_regions`), each with a lighting gain and
    bias of its own (None: one for the whole face). The weights default to the module's constants."""
    prior_weight = PRIOR_WEIGHT if prior_weight is None else prior_weight
    temporal_weight = TEMPORAL_WEIGHT if temporal_weight is None else temporal_weight
    shape_weight = SHAPE_WEIGHT if shape_weight is None else shape_weight
    X = np.asarray(vertices, np.float64)
    centre = centroid(X)
    k = 0 if basis is None else basis.shape[2]
    theta = np.zeros(6 + k) if start is None or len(start) != 6 + k else np.asarray(start, np.float64).copy()
    use = np.flatnonzero(weights > 0)
    use = use[:: max(1, -(-len(use) // MAX_VERTICES))]   # evenly over the mesh: neighbours say much the same
    if len(use) < 20:
        return Refinement(np.zeros(6 + k))
    kind = "perspective" if K is not None else "orthographic"
    anchors = np.asarray(anchors, np.int64)
    points = []   # (share of the photometric weight, vertices (P, 1), target pixels (P, 2))
    if len(anchors):
        # the landmark fit's pixels and (a quadratic pull, so one target: their weighted mean)
        # where the last frame's refinement would put them
        target, share = project(X[anchors], K, kind), prior_weight
        if start is not None:
            held = project(_moved(X[anchors], centre, theta, None if basis is None else basis[anchors]), K, kind)
            target = (prior_weight * target + temporal_weight * held) / (prior_weight + temporal_weight)
            share = prior_weight + temporal_weight
        points.append((share / len(anchors), anchors[:, None], target))
    # the face's box (grown by a margin the motion stays within) is all the pyramid needs
    px0 = project(X[use], K, kind)
    lo, hi = point_bounds(px0)
    margin = CROP_MARGIN * (hi - lo) + 8
    lo, hi = np.floor(lo - margin).astype(int).clip(0, None), np.ceil(hi + margin).astype(int)
    grey = grey[lo[1]:hi[1], lo[0]:hi[0]]
    if min(grey.shape) < 8:
        return Refinement(np.zeros(6 + k))
    B_use = None if basis is None else basis[use]
    for scale in LEVELS if levels is None else levels:
        levels_and_gradients = _pyramid_level(grey, scale)
        for _ in range(STEPS):
            Xm = _moved(X[use], centre, theta, B_use)
            px = (project(Xm, K, kind) - lo) * scale     # pixels of the cropped level
            looked_up, inside = sample(levels_and_gradients, px)
            values = looked_up[:, 0]
            w = weights[use] * inside
            # lighting: the frame's grey = gain * template + bias (+ the components' mix), this step
            A, ridged = lighting_basis(template[use], None if regions is None else regions[use])
            ridge = np.where(ridged, COMPONENT_RIDGE * float(w.sum()), 0.0)   # components: near the mean face
            coef = np.linalg.solve(A.T @ (A * w[:, None]) + np.diag(ridge) + 1e-9 * np.eye(A.shape[1]),
                                   A.T @ (w * values))
            r = values - A @ coef
            w = w * np.where(np.abs(r) <= HUBER, 1.0, HUBER / np.maximum(np.abs(r), 1e-9))
            grad = looked_up[:, 1:] * scale
            J = _image_jacobian(grad, Xm, centre, theta, B_use, K)
            H = J.T @ (J * w[:, None])
            g = J.T @ (w * r)
            total = float(w.sum())   # the point terms' weights are relative to the photometric term's
            for share, pv, targets in points:
                Hp, gp = _pixel_term(X, centre, theta, basis, K, pv, np.ones(pv.shape), targets)
                H += share * total * Hp
                g += share * total * gp
            if k:
                H[6:, 6:] += shape_weight * total * np.eye(k)
                g[6:] += shape_weight * total * theta[6:]
            theta -= np.linalg.solve(H + 1e-6 * np.eye(6 + k), g)
    return Refinement(theta.copy())


def track_pose(vertices: np.ndarray, K: np.ndarray | None, tracks: tuple, steps: int = 4) -> Refinement:
    """The rigid motion (rotation about the centroid, translation: a :class:`Refinement`) that moves
    ``vertices`` (V, 3) float64 camera space (``K`` (3, 3), or None: orthographic) so the corners
    tracked from the last frame land where they were found: ``tracks`` (vertices (P, 3) int, mix
    (P, 3), offsets (P, 2), found (P, 2) px[, error (P,) px: the forward-backward miss of each
    track]), each corner at its vertices' mixed pixels plus its offset (:mod:`.surface_features`);
    Huber weights beyond TRACK_HUBER_PX, and a track that missed by ``error`` on its way back
    weighs 1 / (1 + (error / TRACK_ERROR_PX)^2)."""
    X = np.asarray(vertices, np.float64)
    centre = centroid(X)
    tv, mix, offsets, found = tracks[:4]
    confidence = None if len(tracks) < 5 else 1.0 / (1.0 + (np.asarray(tracks[4]) / TRACK_ERROR_PX) ** 2)
    theta = np.zeros(6)
    for _ in range(steps):
        H, g = _pixel_term(X, centre, theta, None, K, tv, mix, found - offsets, TRACK_HUBER_PX, confidence)
        theta -= np.linalg.solve(H + 1e-6 * np.eye(6), g)
    return Refinement(theta)
