"""The background plate: what the scene behind the face looked like when the face was elsewhere
(docs/architecture.md "Stages", 4; issue 16).

Per pixel, a running estimate of the background from the frames where the face (its region
grown by a margin) did not cover it: the first observation is taken as it is, later ones are
averaged in with a constant rate (an exponential mean of the recent observations, so slow
changes of light or scene are followed), and the frame each pixel was last seen in is kept, so
an estimate older than ``max_age`` frames is no longer used. When the camera moves, the plate is
registered to the current frame by a homography of the background: corners outside the face
tracked from the previous frame (pyramidal Lucas-Kanade on a downscaled grey frame) and
:func:`cv2.findHomography` with RANSAC; the motions are chained and the plate is warped only when
their product moves a corner of the frame by ``STATIC_PX`` or more (each warp resamples the plate:
a still camera's sub-pixel jitter must not blur it), and when no homography explains the motion
the plate is forgotten.

:class:`BackgroundPlate` holds the state (arrays only); the compositor calls :meth:`update` once a
frame with the input frame and the face's region, and :meth:`take` on the pixels it fills.
Images are (H, W, 3) uint8 BGR; masks (H, W) bool or uint8 (non-zero = set).
"""

from __future__ import annotations

import cv2
import numpy as np

SMALL_FACTOR = 4           # the registration works on the grey frame downscaled by this factor
STATIC_PX = 0.5            # motion of the frame's corners (full-resolution px) the plate may lag before it is warped
MIN_INLIERS = 12           # RANSAC inliers a homography needs to be trusted
NEVER = -1.0e9             # last-seen frame of a pixel never seen
RING_PX = 8                # the light is compared on the known background this close to the fill, px


def face_region(shape: tuple[int, int], projected_px: np.ndarray, margin_px: float) -> np.ndarray:
    """(H, W) uint8 0/1: the convex hull of a face's projected vertices ((V, 2) pixels) grown by
    ``margin_px`` pixels, cut to the frame of ``shape`` (H, W). Empty for fewer than 3 vertices."""
    h, w = shape
    mask = np.zeros((h, w), np.uint8)
    pts = np.asarray(projected_px, np.float32).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 3:
        return mask
    hull = np.round(cv2.convexHull(pts)).astype(np.int32)
    cv2.fillConvexPoly(mask, hull, 1)
    r = int(np.ceil(max(margin_px, 0.0)))
    if r > 0:  # a convex polygon grown by a disk: its outline drawn 2r + 1 wide with round joins
        cv2.polylines(mask, [hull], True, 1, thickness=2 * r + 1, lineType=cv2.LINE_8)
    return mask


def occluded_region(shape: tuple[int, int], projected_px: np.ndarray, margin_px: float,
                    hidden: np.ndarray | None = None) -> np.ndarray | None:
    """(H, W) uint8 0/1: what the plate must not learn from a frame of ``shape`` (H, W): the face
    (:func:`face_region` of its (V, 2) ``projected_px`` grown by ``margin_px``) and the ``hidden``
    (H, W) pixels (non-zero: e.g. a hand in front of it). None when there is neither."""
    occluded = face_region(shape, projected_px, margin_px) if len(projected_px) else None
    if hidden is not None:
        hidden = (np.asarray(hidden) != 0).view(np.uint8)
        occluded = hidden if occluded is None else occluded | hidden
    return occluded


class BackgroundPlate:
    """Per-pixel background of a (H, W) video, learned where the face is not.

    rate: weight of a new observation in the running mean (0..1]; max_age: frames after which a
    pixel's estimate is no longer used; register: follow a moving camera by a homography of the
    background (False: a static camera is assumed).

    State: ``colour`` (H, W, 3) float32 BGR the estimate, ``last_seen`` (H, W) float32 the frame
    index each pixel was last observed in (``NEVER`` if not), ``frame`` the index of the newest
    frame, ``moved`` whether the last update warped the plate, ``homography`` (3, 3) the last one
    applied (previous frame -> this one, pixels) or None.
    """

    def __init__(self, width: int, height: int, *, rate: float = 0.2, max_age: int = 150, register: bool = True):
        if not 0.0 < rate <= 1.0:
            raise ValueError(f"rate must be in (0, 1], got {rate}")
        if max_age < 1:
            raise ValueError(f"max_age must be >= 1, got {max_age}")
        self.width, self.height = int(width), int(height)
        self.rate, self.max_age, self.register = float(rate), int(max_age), bool(register)
        self.scale = 1.0 / SMALL_FACTOR
        self._stamp = np.zeros((self.height, self.width), np.float32)
        self.reset()

    def reset(self) -> None:
        """Forget everything seen."""
        self.colour = np.zeros((self.height, self.width, 3), np.float32)
        self.last_seen = np.full((self.height, self.width), NEVER, np.float32)
        self.frame = -1
        self.moved = False
        self.homography: np.ndarray | None = None
        self._pending = np.eye(3)   # the background's motion since the plate was last warped
        self._prev_small: np.ndarray | None = None
        self._prev_bg_small: np.ndarray | None = None

    # -- learning ----------------------------------------------------------------------------------
    def update(self, frame_bgr: np.ndarray, occluded: np.ndarray | None,
               keep: tuple[int, int, int, int] | None = None) -> None:
        """Take one frame: register the plate to it (camera motion), then average in its pixels
        outside ``occluded`` ((H, W) mask: the face grown by a margin, hands, anything in front of
        the background; None: nothing). ``keep``: the box (x0, y0, x1, y1) whose memory matters
        (around the face; None: the frame): only it learns, and when the camera moves only it is
        warped, the rest is forgotten."""
        if frame_bgr.shape != (self.height, self.width, 3) or frame_bgr.dtype != np.uint8:
            raise ValueError(f"frame must be ({self.height}, {self.width}, 3) uint8, got {frame_bgr.shape} "
                             f"{frame_bgr.dtype}")
        self.frame += 1
        if occluded is None:
            seen = np.full((self.height, self.width), 255, np.uint8)
        else:
            seen = cv2.compare(np.asarray(occluded).view(np.uint8) if np.asarray(occluded).dtype == bool
                               else np.asarray(occluded), 0, cv2.CMP_EQ)
        self.moved = False
        if self.register:
            h, w = self.height // SMALL_FACTOR, self.width // SMALL_FACTOR
            small = cv2.cvtColor(cv2.resize(frame_bgr[:h * SMALL_FACTOR, :w * SMALL_FACTOR], (w, h),
                                            interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2GRAY)
            bg_small = cv2.resize(seen[:h * SMALL_FACTOR, :w * SMALL_FACTOR], (w, h), interpolation=cv2.INTER_NEAREST)
            if self._prev_small is not None:
                self._follow_camera(small, bg_small, keep)
            self._prev_small, self._prev_bg_small = small, bg_small
        x0, y0, x1, y1 = self._clip(keep)
        if x1 <= x0 or y1 <= y0:
            return
        box = (slice(y0, y1), slice(x0, x1))
        seen, last_seen, colour, frame = seen[box], self.last_seen[box], self.colour[box], frame_bgr[box]
        # The first observation of a pixel (or one after its estimate aged out) is taken as it is.
        fresh = cv2.compare(last_seen, float(self.frame - self.max_age), cv2.CMP_GE)
        first = cv2.bitwise_and(seen, cv2.bitwise_not(fresh))
        if cv2.countNonZero(first):
            cv2.accumulateWeighted(frame, colour, 1.0, mask=first)  # rate 1: a copy
        cv2.accumulateWeighted(frame, colour, self.rate, mask=cv2.bitwise_and(seen, fresh))
        stamp = self._stamp[box]
        stamp.fill(self.frame)
        cv2.copyTo(stamp, seen, last_seen)

    def _clip(self, box) -> tuple[int, int, int, int]:
        x0, y0, x1, y1 = box if box is not None else (0, 0, self.width, self.height)
        return max(0, int(x0)), max(0, int(y0)), min(self.width, int(x1)), min(self.height, int(y1))

    def _follow_camera(self, small: np.ndarray, bg_small: np.ndarray, keep) -> None:
        """Warp the plate by the background's homography from the previous frame to this one
        (estimated on the downscaled grey frames ``small``, background mask ``bg_small``);
        forget it when the motion is not a homography."""
        mask = self._prev_bg_small & bg_small
        pts = cv2.goodFeaturesToTrack(self._prev_small, 64, 0.01, 6, mask=mask)
        if pts is None or len(pts) < MIN_INLIERS:
            return  # nothing to track: the plate stays where it is
        nxt, status, _ = cv2.calcOpticalFlowPyrLK(self._prev_small, small, pts, None, winSize=(9, 9), maxLevel=2)
        ok = status.ravel() == 1
        p0, p1 = pts.reshape(-1, 2)[ok], nxt.reshape(-1, 2)[ok]
        if len(p0) < MIN_INLIERS:
            self.reset_memory()
            return
        if np.median(np.linalg.norm(p1 - p0, axis=1)) < 0.1 * STATIC_PX * self.scale:
            return  # still: the chained motion stays as it is
        H_small, inliers = cv2.findHomography(p0, p1, cv2.RANSAC, 0.5)
        if H_small is None or int(inliers.sum()) < max(MIN_INLIERS, len(p0) // 3):
            self.reset_memory()
            return
        S = np.diag([self.scale, self.scale, 1.0])
        self._pending = np.linalg.inv(S) @ H_small @ S @ self._pending
        self._pending /= self._pending[2, 2]
        x0, y0, x1, y1 = self._clip(keep)
        corners = np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]], np.float64)
        moved = cv2.perspectiveTransform(corners[None], self._pending)[0] - corners
        if np.abs(moved).max() >= STATIC_PX:
            self.warp(self._pending, keep)

    def warp(self, H: np.ndarray, keep: tuple[int, int, int, int] | None = None) -> None:
        """Move the plate by the homography ``H`` (3, 3): a pixel x of the plate goes to H x;
        pixels that come from outside the old plate are unknown, and so is everything outside
        ``keep`` (x0, y0, x1, y1; None: the frame), which alone is resampled."""
        x0, y0, x1, y1 = self._clip(keep)
        Hk = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]]) @ H
        size = (x1 - x0, y1 - y0)
        # A known pixel must not take a never-seen neighbour's colour: it stays known only when
        # its whole 2x2 bilinear footprint was.
        seen = cv2.erode(cv2.compare(self.last_seen, NEVER / 2, cv2.CMP_GT), np.ones((2, 2), np.uint8))
        seen = cv2.warpPerspective(seen, Hk, size, flags=cv2.INTER_NEAREST, borderValue=0)
        last = cv2.warpPerspective(self.last_seen, Hk, size, flags=cv2.INTER_NEAREST, borderValue=NEVER)
        colour = cv2.warpPerspective(self.colour, Hk, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        last[seen == 0] = NEVER
        self.last_seen.fill(NEVER)
        self.last_seen[y0:y1, x0:x1] = last
        self.colour[y0:y1, x0:x1] = colour
        self.homography = np.asarray(H, np.float64)
        self._pending = np.eye(3)
        self.moved = True

    def reset_memory(self) -> None:
        """Forget the estimate (the camera moved in a way the plate cannot follow), keep the frame count."""
        frame = self.frame
        self.reset()
        self.frame = frame

    # -- use ---------------------------------------------------------------------------------------
    def known(self, box: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """(h, w) bool: pixels of ``box`` (x0, y0, x1, y1; None: the frame) whose estimate is fresh
        (seen within ``max_age`` frames)."""
        x0, y0, x1, y1 = box if box is not None else (0, 0, self.width, self.height)
        return self.last_seen[y0:y1, x0:x1] >= self.frame - self.max_age

    def known_at(self, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        """(N,) bool: whether the estimate of each pixel (``xs``, ``ys``) (N,) int is fresh, as :meth:`known`."""
        return self.last_seen[ys, xs] >= self.frame - self.max_age

    def take(self, crop: np.ndarray, fill: np.ndarray, source: np.ndarray, box: tuple[int, int, int, int],
             blend_px: float = 3.0) -> np.ndarray:
        """Lay the plate over the filled pixels of ``crop`` ((h, w, 3) uint8, the frame's ``box``
        (x0, y0, x1, y1), already filled; modified in place) where it is known: ``fill`` (h, w) the
        filled pixels, ``source`` (h, w) the background pixels around them. The plate's colour is
        shifted by the mean difference between the crop and the plate on the ``source`` pixels it
        knows within ``RING_PX`` of the fill (the light now), and it fades into the fill over ``blend_px`` pixels at the border of
        what it knows. Returns the (h, w) float32 weight the plate got (0 outside ``fill``)."""
        x0, y0 = box[0], box[1]
        fill_u8 = (np.asarray(fill) != 0).view(np.uint8) if np.asarray(fill).dtype == bool else \
            (np.asarray(fill) != 0).astype(np.uint8)
        weight = np.zeros(fill_u8.shape, np.float32)
        rx, ry, rw, rh = cv2.boundingRect(fill_u8)
        if rw == 0 or rh == 0:
            return weight
        # Work on the fill's bounding box grown by the ring the light is measured on.
        h, w = fill_u8.shape
        pad = RING_PX + int(np.ceil(blend_px))
        sx0, sy0, sx1, sy1 = max(0, rx - pad), max(0, ry - pad), min(w, rx + rw + pad), min(h, ry + rh + pad)
        sub = (slice(sy0, sy1), slice(sx0, sx1))
        f = fill_u8[sub]
        known = self.known((x0 + sx0, y0 + sy0, x0 + sx1, y0 + sy1))
        if not (known & (f != 0)).any():
            return weight
        plate = self.colour[y0 + sy0:y0 + sy1, x0 + sx0:x0 + sx1]
        part = crop[sub]
        near = cv2.dilate(f, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * RING_PX + 1,) * 2)) != 0
        ring = known & (np.asarray(source)[sub] != 0) & (f == 0) & near
        shift = np.zeros(3, np.float32)
        if ring.sum() >= 16:
            shift = (part[ring].astype(np.float32) - plate[ring]).mean(axis=0)
        if blend_px > 0:
            dist = cv2.distanceTransform(known.astype(np.uint8), cv2.DIST_L2, 3)
            wsub = np.clip(dist / float(blend_px), 0.0, 1.0).astype(np.float32)
        else:
            wsub = known.astype(np.float32)
        wsub[f == 0] = 0.0
        w3 = wsub[..., None]
        mixed = part.astype(np.float32) * (1.0 - w3) + (plate + shift) * w3
        np.copyto(part, np.clip(np.rint(mixed), 0, 255).astype(np.uint8), where=(wsub > 0)[..., None])
        weight[sub] = wsub
        return weight
