"""Gaze from the fitted head and the irises: a geometric eyeball model (Le 2014, chapter 8).

Each eye is a sphere fixed in the head: radius :data:`EYEBALL_RADIUS_MM` (an adult eye's, 24 mm
long, varies little between people), its iris a circle of radius ``rho`` whose centre lies
``D = sqrt(r² - rho²)`` ahead of the eyeball's centre. The limbus is taken to lie at the eye's
opening (the iris sits just behind the lids), so the centre is ``D`` behind the opening along the
head's forward axis (model +z, through the fitted rotation). Where the opening is comes from two
sources, each for what it measures well:

* across the face: the iris network's lids, each frame, their corners' midpoint back-projected
  at the depth the fit gives the eye, plus the offset from there to the lids' centroid (model
  mm) averaged over the person's first ``learn_frames`` frames (the corners hardly move as the eye
  turns; the centroid follows the lids);
* up and down: this frame's face-mesh eye corners (the points the fit was made from, so not
  lagging behind a fast head as the smoothed fitted pose does), plus the offset in the head from
  them to the iris network's lids' centroid averaged over those frames (without the face mesh's
  points: the lids' centroid averaged in head coordinates, placed by the fitted pose);
* ``rho`` (mm) is the iris network's limbus radius along the eye's corner axis (where the lids
  do not cover it), carried to mm at the eye's depth, the median over those frames (clamped to
  :data:`IRIS_RADIUS_RANGE_MM`; :data:`IRIS_RADIUS_MM` before).

The head's rotation places the centres, so an error in the fitted head rotation turns the gaze
by about as much (docs/results/gaze.md).

Every frame, the iris centre's pixel is back-projected to a ray that meets the sphere of radius
``D`` about the centre (the circle of limbus centres as the eye turns); the gaze ray goes
from the centre through that point. A ray that misses the sphere takes its point nearest to the centre, with
a confidence that falls with the miss. Both eyes are combined, weighted by confidence, into one
ray from between the eyeballs; their **vergence** is the angle between the two rays, and their
**fixation** point the midpoint of the rays' closest approach when they converge in front.

**Blinks** are flagged from the lids, not guessed: an eye whose opening (:func:`eye_opening`) falls
below :data:`CLOSED_SHARE` of its usual opening (the 90th percentile of the frames seen), or below
:data:`CLOSED_OPENING`, is closed; its ray is NaN and its confidence 0; when both are closed the
combined ray is NaN too.

Angles: yaw positive toward the image's right (the subject's left when facing the camera), pitch
positive up, degrees; in camera space (OpenCV: x right, y down, z away) and, for the eye in the
head, in model space.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from facesculpt.geometry.eye_points import IBUG_EYE_LIDS, MESH_EYE_CORNERS, MESH_EYE_LIDS, eye_opening

#: An adult eyeball's radius, mm.
EYEBALL_RADIUS_MM = 12.0
#: The iris's radius before it is learned (the horizontal visible iris diameter is about 11.8 mm),
#: and the range a learned one is clamped to, mm.
IRIS_RADIUS_MM = 5.9
IRIS_RADIUS_RANGE_MM = (4.8, 7.0)
#: Frames over which the eyeballs are learned.
LEARN_FRAMES = 30
#: An eye is closed below this share of its usual opening, or below this opening at all.
CLOSED_SHARE = 0.45
CLOSED_OPENING = 0.08
#: Frames whose openings set an eye's usual opening (90th percentile).
OPENING_MEMORY = 300


@dataclass
class Gaze:
    """One face's gaze in one frame. Camera space (mm, OpenCV axes) unless said otherwise.

    centres (2, 3): the eyeballs' centres (eye 0 the right eye); directions (2, 3): unit gaze
    directions (NaN where closed); eye_angles (2, 2): each eye's yaw, pitch in camera space (deg);
    confidences (2,) 0..1; closed (2,) bool: blink flags; openings (2,): :func:`eye_opening`;
    origin (3,), direction (3,): the combined ray (direction NaN when both eyes are closed);
    yaw_deg, pitch_deg: its angles in camera space; head_yaw_deg, head_pitch_deg: in the head
    (0, 0: looking straight out of the face); vergence_deg: the angle between the two rays
    (positive when they converge; NaN unless both are open); fixation (3,): where they meet (NaN
    unless they converge in front); confidence 0..1; learned: the eyeballs are learned (before
    that they come from the frames seen so far); irises (2, 5, 2) and lids (2, 16, 2): the pixels
    it was estimated from; sphere_mm: the radius (camera units) of the sphere the iris centre
    moves on."""

    centres: np.ndarray
    directions: np.ndarray
    eye_angles: np.ndarray
    confidences: np.ndarray
    closed: np.ndarray
    openings: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    yaw_deg: float
    pitch_deg: float
    head_yaw_deg: float
    head_pitch_deg: float
    vergence_deg: float
    fixation: np.ndarray
    confidence: float
    learned: bool
    irises: np.ndarray | None = None
    lids: np.ndarray | None = None
    sphere_mm: float = 0.0

    @property
    def blink(self) -> bool:
        """Both eyes closed."""
        return bool(np.all(self.closed))


def yaw_pitch(direction: np.ndarray, camera: bool = True) -> np.ndarray:
    """(..., 2) yaw, pitch in degrees of unit directions (..., 3): in camera space (x right, y
    down, z away; looking into the camera is -z) or, ``camera=False``, in model space (x to the
    subject's left, y up, z out of the face)."""
    d = np.asarray(direction, np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    if camera:
        y, z = -y, -z
    return np.degrees(np.stack([np.arctan2(x, z), np.arctan2(y, np.hypot(x, z))], axis=-1))


def direction_from_angles(yaw_deg, pitch_deg, camera: bool = True) -> np.ndarray:
    """The unit direction (..., 3) of yaw, pitch in degrees (the inverse of :func:`yaw_pitch`)."""
    a, b = np.radians(yaw_deg), np.radians(pitch_deg)
    d = np.stack([np.cos(b) * np.sin(a), np.sin(b), np.cos(b) * np.cos(a)], axis=-1)
    return d * np.array([1.0, -1.0, -1.0]) if camera else d


def eye_lid_vertices(model) -> tuple[np.ndarray, np.ndarray]:
    """The model vertices of each eye's lids: (2, n) int64, eye 0 the right eye (the face mesh's
    16 lid points, else the iBUG-68 landmark vertices 37-42 and 43-48). A sparse model without
    them raises ValueError."""
    if model.dense:
        return np.array(MESH_EYE_LIDS[0]), np.array(MESH_EYE_LIDS[1])
    names = {str(n): int(v) for n, v in zip(model.landmark_names, np.asarray(model.landmark_vertices).ravel())}
    missing = [n for eye in IBUG_EYE_LIDS for n in eye if n not in names]
    if missing:
        raise ValueError(f"the model has no landmark vertices for iBUG points {', '.join(missing)}: no gaze")
    return tuple(np.array([names[n] for n in eye]) for eye in IBUG_EYE_LIDS)


def ray_sphere(origin: np.ndarray, ray: np.ndarray, centre: np.ndarray, radius: float) -> tuple[np.ndarray, float]:
    """The nearest point where the ray ``origin + s ray`` (s >= 0, ``ray`` unit) meets the sphere,
    and how far it missed (0 on a hit; else the point is the ray's nearest to the centre, carried
    onto the sphere, and the miss is the distance of the ray from the sphere, same units)."""
    oc = origin - centre
    b = float(ray @ oc)
    c = float(oc @ oc) - radius * radius
    disc = b * b - c
    if disc >= 0.0:
        return origin + (-b - np.sqrt(disc)) * ray, 0.0
    nearest = origin - b * ray
    off = nearest - centre
    dist = float(np.linalg.norm(off))
    return centre + off * (radius / max(dist, 1e-9)), dist - radius


def pixel_rays(K: np.ndarray, pixels: np.ndarray, orthographic: bool) -> tuple[np.ndarray, np.ndarray]:
    """Back-projected rays of pixels (N, 2) (pixel indices): origins (N, 3) and unit directions
    (N, 3) in camera space (perspective: from the camera's centre; orthographic: from z = -1e4
    along +z, x and y the pixels)."""
    px = np.asarray(pixels, np.float64)
    if orthographic:
        return np.column_stack([px, np.full(len(px), -1e4)]), np.tile([0.0, 0.0, 1.0], (len(px), 1))
    d = np.column_stack([(px - K[:2, 2]) / np.array([K[0, 0], K[1, 1]]), np.ones(len(px))])
    return np.zeros((len(px), 3)), d / np.linalg.norm(d, axis=1, keepdims=True)


@dataclass
class EyeballLearning:
    """What is learned of one person's eyes (state of :func:`estimate_gaze`, one per person):
    the sums of the lids' centres (2, 3) model mm over the frames learned, the iris radii seen
    (mm), and each eye's recent openings."""

    learn_frames: int = LEARN_FRAMES
    frames: int = 0
    centre_sum: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))  # of the lids' offsets
    model_sum: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))  # of the lids' centroids in the head
    iris_radii: list = field(default_factory=list)
    openings: tuple = field(default_factory=lambda: (deque(maxlen=OPENING_MEMORY), deque(maxlen=OPENING_MEMORY)))
    _levels: dict = field(default_factory=dict, repr=False)

    @property
    def learned(self) -> bool:
        return self.frames >= self.learn_frames

    def iris_radius(self) -> float:
        """The iris radius (mm) learned so far (fixed once learned)."""
        if not self.iris_radii:
            return IRIS_RADIUS_MM
        if self.learned and "rho" in self._levels:
            return self._levels["rho"]
        rho = float(np.clip(np.median(self.iris_radii), *IRIS_RADIUS_RANGE_MM))
        if self.learned:
            self._levels["rho"] = rho
        return rho

    def openings_level(self, eye: int) -> float:
        """The eye's usual opening: the 90th percentile of its recent openings, brought up to date
        every 10 frames (NaN before 5)."""
        seen = self.openings[eye]
        if len(seen) < 5:
            return np.nan
        level, age = self._levels.get(eye, (np.nan, 10))
        if age >= 10:
            level, age = float(np.percentile(seen, 90)), 0
        self._levels[eye] = (level, age + 1)
        return level


def _limbus_radius_px(iris: np.ndarray, lids: np.ndarray) -> float:
    """Half the distance (px) between the two limbus points of an iris (5, >=2) that lie most
    along the eye's corner axis (lids (16, >=2)): the lids seldom cover the iris there."""
    axis = lids[8, :2] - lids[0, :2]
    axis = axis / max(float(np.linalg.norm(axis)), 1e-9)
    along = (iris[1:, :2] - iris[0, :2]) @ axis
    return float(along.max() - along.min()) / 2.0


def _closest_approach(c0, d0, c1, d1) -> tuple[float, float]:
    """Parameters (s0, s1) of the points of the lines c0 + s0 d0 and c1 + s1 d1 (unit d) nearest
    each other (NaN for parallel lines)."""
    w = c0 - c1
    b, d, e = float(d0 @ d1), float(d0 @ w), float(d1 @ w)
    den = 1.0 - b * b
    if den < 1e-9:
        return np.nan, np.nan
    return (b * e - d) / den, (e - b * d) / den


def _back_project(px: np.ndarray, depth: float, K: np.ndarray | None) -> np.ndarray:
    """The camera-space point (3,) at ``depth`` on the ray of pixel ``px`` (2,) (K None: an
    orthographic fit, whose camera x, y are the pixels)."""
    if K is None:
        return np.array([px[0], px[1], depth])
    return np.array([(px[0] - K[0, 2]) / K[0, 0] * depth, (px[1] - K[1, 2]) / K[1, 1] * depth, depth])


def _openings(mv, lid_vertices, lids, R, t, s, K) -> tuple[np.ndarray, np.ndarray]:
    """Each eye's corners' midpoint (2, 3) camera space, where the iris network's lids (2, 16,
    >=2) pixels put it at the depth the fit gives the eye's lid vertices, and the offset (2, 3)
    model mm from it to the centroid of those lids (K None: orthographic)."""
    mids, offsets = np.empty((2, 3)), np.empty((2, 3))
    for e in (0, 1):
        depth = float((s * (R @ mv[np.asarray(lid_vertices[e])].mean(axis=0)) + t)[2])
        mids[e] = _back_project((lids[e, 0, :2] + lids[e, 8, :2]) / 2.0, depth, K)
        centroid = _back_project(lids[e, :, :2].mean(axis=0), depth, K)
        offsets[e] = R.T @ (centroid - mids[e]) / s
    return mids, offsets


def estimate_gaze(fit, lid_vertices, irises: np.ndarray, lids: np.ndarray, state: EyeballLearning,
                  mesh_points: np.ndarray | None = None) -> Gaze:
    """One face's :class:`Gaze` in one frame. fit: its :class:`FitResult` (R, t, scale,
    projection, K, model_vertices (V, 3) model mm); lid_vertices: each eye's lid vertices
    (:func:`eye_lid_vertices`); irises (2, 5, >=2) and lids (2, 16, >=2): the iris network's
    points (pixel indices, eye 0 the right eye); state: the person's :class:`EyeballLearning`
    (updated here); mesh_points: this frame's face-mesh points (468, >=2) px, whose lids place the
    eyes' height (else the fitted head, whose pose the fitter smooths, does)."""
    R, t, s = np.asarray(fit.R, np.float64), np.asarray(fit.t, np.float64), float(fit.scale)
    ortho = fit.projection != "perspective"
    irises, lids = np.asarray(irises, np.float64), np.asarray(lids, np.float64)
    mv = np.asarray(fit.model_vertices, np.float64)
    openings = eye_opening(lids)
    levels = np.array([state.openings_level(e) for e in (0, 1)])
    closed = (openings < CLOSED_OPENING) | (openings < CLOSED_SHARE * np.nan_to_num(levels, nan=0.0))
    for e in (0, 1):
        state.openings[e].append(float(openings[e]))
    K = None if fit.K is None else np.asarray(fit.K, np.float64)
    mids, offsets = _openings(mv, lid_vertices, lids, R, t, s, None if ortho else K)
    net_centres = mids + s * (offsets @ R.T)  # the iris network's lids' centroids, camera space
    if mesh_points is None:  # the network's lids' centroid in head coordinates
        height_from, in_model = t, (net_centres - t) @ R / s
    else:  # the face mesh's lids of this frame, and the offset from them to the network's in the head
        height_from = np.stack([_back_project(np.asarray(mesh_points, np.float64)[list(MESH_EYE_CORNERS[e]), :2]
                                              .mean(axis=0), float(mids[e, 2]), None if ortho else K) for e in (0, 1)])
        in_model = (net_centres - height_from) @ R / s
    if not state.learned and not closed.any():
        state.frames += 1
        state.centre_sum += offsets
        state.model_sum += in_model
    offsets = state.centre_sum / state.frames if state.frames else offsets
    in_model = state.model_sum / state.frames if state.frames else in_model
    forward = np.array([0.0, 0.0, 1.0])
    rho = state.iris_radius()
    depth_mm = np.sqrt(EYEBALL_RADIUS_MM ** 2 - rho ** 2)
    centres = mids + s * ((offsets - depth_mm * forward) @ R.T)
    # across the face the lids' corners of this frame place the eye; its height is where the lids'
    # centroid sat in the head over the first frames (the lids follow the gaze up and down)
    up = R[:, 1]
    by_model = s * ((in_model - depth_mm * forward) @ R.T) + height_from
    centres += np.outer((by_model - centres) @ up, up)
    origins, rays = pixel_rays(K, irises[:, 0, :2], ortho)
    directions = np.full((2, 3), np.nan)
    confidences = np.zeros(2)
    forward_cam = R @ forward
    for e in (0, 1):
        if not state.learned and not closed.any():
            rho_px = _limbus_radius_px(irises[e], lids[e])
            px_per_mm = s if ortho else float(K[0, 0]) / max(float(centres[e, 2]), 1e-6)
            state.iris_radii.append(rho_px / px_per_mm)
        if closed[e]:
            continue
        point, miss = ray_sphere(origins[e], rays[e], centres[e], depth_mm * s)
        d = point - centres[e]
        directions[e] = d / max(float(np.linalg.norm(d)), 1e-9)
        view = -rays[e]
        level = levels[e] if np.isfinite(levels[e]) else 0.3
        open_f = np.clip((openings[e] / level - CLOSED_SHARE) / 0.3, 0.0, 1.0)
        confidences[e] = (np.exp(-(miss / (rho * s)) ** 2) * open_f * np.clip(forward_cam @ view, 0.0, 1.0) ** 2)
    gaze = _combined(centres, directions, confidences, closed, openings, R, state.learned)
    gaze.irises, gaze.lids, gaze.sphere_mm = irises[..., :2], lids[..., :2], float(depth_mm * s)
    return gaze


def _combined(centres, directions, confidences, closed, openings, R, learned) -> Gaze:
    """Both eyes' rays into one :class:`Gaze`."""
    open_eyes = ~closed
    origin = centres.mean(axis=0)
    vergence, fixation = np.nan, np.full(3, np.nan)
    if open_eyes.all():
        w = np.maximum(confidences, 1e-6)
        direction = (w[:, None] * directions).sum(axis=0)
        cos = float(np.clip(directions[0] @ directions[1], -1.0, 1.0))
        s0, s1 = _closest_approach(centres[0], directions[0], centres[1], directions[1])
        converge = np.isfinite(s0) and s0 > 0 and s1 > 0
        vergence = float(np.degrees(np.arccos(cos))) * (1.0 if converge else -1.0)
        if converge and max(s0, s1) < 1e5:
            fixation = 0.5 * (centres[0] + s0 * directions[0] + centres[1] + s1 * directions[1])
    elif open_eyes.any():
        direction = directions[int(np.flatnonzero(open_eyes)[0])].copy()
    else:
        direction = np.full(3, np.nan)
    norm = float(np.linalg.norm(direction))
    direction = direction / norm if norm > 0 else np.full(3, np.nan)
    yaw, pitch = yaw_pitch(direction)
    head_yaw, head_pitch = yaw_pitch(R.T @ direction, camera=False)
    confidence = float(confidences[open_eyes].max()) if open_eyes.any() else 0.0
    if open_eyes.all():
        confidence = float(np.sqrt(confidences[0] * confidences[1])) if confidences.min() > 0 else confidence / 2
    return Gaze(centres=centres, directions=directions, eye_angles=yaw_pitch(directions), confidences=confidences,
                closed=closed.copy(), openings=openings, origin=origin, direction=direction,
                yaw_deg=float(yaw), pitch_deg=float(pitch), head_yaw_deg=float(head_yaw),
                head_pitch_deg=float(head_pitch), vergence_deg=vergence, fixation=fixation,
                confidence=confidence, learned=bool(learned))


#: The columns of a gaze in tables (``process --export-params`` with ``--gaze``): the combined
#: ray's yaw and pitch in camera space and in the head (degrees), the vergence (degrees), the
#: confidence (0..1) and each eye's blink flag (1 closed, 0 open).
GAZE_NAMES = ("gaze_yaw_deg", "gaze_pitch_deg", "gaze_head_yaw_deg", "gaze_head_pitch_deg", "gaze_vergence_deg",
              "gaze_confidence", "blink_right", "blink_left")


def gaze_values(gaze: Gaze) -> tuple:
    """The values of :data:`GAZE_NAMES` of one :class:`Gaze` (NaN where there is none)."""
    return (gaze.yaw_deg, gaze.pitch_deg, gaze.head_yaw_deg, gaze.head_pitch_deg, gaze.vergence_deg,
            gaze.confidence, int(gaze.closed[0]), int(gaze.closed[1]))
