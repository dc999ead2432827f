"""Eye contact: each iris moved inside its eye's opening to where it would be if the eye looked
into the camera (issue 48), smoothly turned off when the person looks far away or blinks.

Plain functions of arrays. The eye's opening is the polygon of its 16 lid points (the iris
network's order: lower lid 0..8, upper lid 9..15); inside it every pixel is moved by the iris's
shift times a weight that is 1 a little in from the lids and falls smoothly to 0 at them, so the
iris and the sclera around it move, the lids and everything outside stay exactly as they were.
What the lids hid stays hidden: a shift is a warp of what is seen, not a new eyeball.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np


@dataclass(frozen=True)
class EyeContactOptions:
    """The correction's limits (``process --eye-contact DEG``)."""

    limit_deg: float = field(default=15.0, metadata={
        "help": "full correction while the gaze is within this many degrees of the camera", "unit": "degrees",
        "range": (0.0, 60.0)})
    fade_deg: float = field(default=5.0, metadata={
        "help": "beyond the limit the correction fades out over this many degrees", "unit": "degrees",
        "range": (0.0, 30.0)})


EYE_CONTACT_OPTIONS = EyeContactOptions()


def contact_strength(angle_deg: float, closed: bool, limit_deg: float, fade_deg: float) -> float:
    """How much of the shift toward the camera to apply, 0..1: 1 within ``limit_deg`` of the
    camera, a smoothstep down to 0 over the next ``fade_deg``, 0 for a closed eye or no gaze."""
    if closed or not np.isfinite(angle_deg):
        return 0.0
    if angle_deg <= limit_deg:
        return 1.0
    s = float(np.clip((limit_deg + fade_deg - angle_deg) / max(fade_deg, 1e-9), 0.0, 1.0))
    return s * s * (3.0 - 2.0 * s)


def camera_targets(centres: np.ndarray, K: np.ndarray, sphere_mm: float) -> np.ndarray:
    """(2, 2) pixels: where each iris centre would be seen if its eye, centred at ``centres``
    (2, 3) camera mm, looked into the camera (the point ``sphere_mm`` from the centre toward the
    camera's centre), under intrinsics K (3, 3)."""
    centres = np.asarray(centres, np.float64)
    toward = -centres / np.linalg.norm(centres, axis=1, keepdims=True)
    points = centres + sphere_mm * toward
    return (points[:, :2] / points[:, 2:3]) * np.diag(K)[:2] + K[:2, 2]


def _opening_polygon(lids: np.ndarray) -> np.ndarray:
    """The lids (16, 2) as one closed polygon: the lower lid, then the upper lid back."""
    return np.asarray(lids, np.float64)[[0, 1, 2, 3, 4, 5, 6, 7, 8, 15, 14, 13, 12, 11, 10, 9], :2]


def move_iris(image: np.ndarray, lids: np.ndarray, iris: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``image`` (H, W, 3) uint8 with one eye's inside moved by ``shift`` (2,) px: lids (16, >=2)
    and iris (5, >=2) in pixels. Returns a new image; pixels outside the opening are untouched."""
    out = image.copy()
    shift = np.asarray(shift, np.float64)
    if not np.all(np.isfinite(shift)) or np.hypot(*shift) < 0.05:
        return out
    polygon = _opening_polygon(lids)
    H, W = image.shape[:2]
    x0, y0 = np.floor(polygon.min(axis=0)).astype(int) - 2
    x1, y1 = np.ceil(polygon.max(axis=0)).astype(int) + 3
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return out
    ss = 4
    mask = np.zeros(((y1 - y0) * ss, (x1 - x0) * ss), np.uint8)
    cv2.fillPoly(mask, [np.round((polygon - [x0, y0] + 0.5) * ss * 16 - 0.5 * 16).astype(np.int32)], 255,
                 cv2.LINE_AA, shift=4)
    inside = cv2.resize(mask, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    radius = float(np.mean(np.linalg.norm(np.asarray(iris)[1:, :2] - np.asarray(iris)[0, :2], axis=1)))
    depth = cv2.distanceTransform((inside > 0.5).astype(np.uint8), cv2.DIST_L2, 3)
    w = np.clip(depth / max(0.6 * radius, 1.0), 0.0, 1.0)
    w = w * w * (3.0 - 2.0 * w)
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    warped = cv2.remap(image, xs - np.float32(shift[0]) * w, ys - np.float32(shift[1]) * w, cv2.INTER_CUBIC,
                       borderMode=cv2.BORDER_REPLICATE)
    box = out[y0:y1, x0:x1].astype(np.float32)
    a = inside[..., None]
    out[y0:y1, x0:x1] = np.clip(a * warped + (1.0 - a) * box + 0.5, 0, 255).astype(np.uint8)
    return out


def eye_contact(image: np.ndarray, K: np.ndarray, gaze, options: EyeContactOptions = EYE_CONTACT_OPTIONS) -> np.ndarray:
    """``image`` with both irises of one face moved toward looking into the camera. ``gaze``: its
    :class:`facesculpt.nodes.fitter.gaze.Gaze` (centres, directions, closed, the irises and lids it
    was estimated from, ``sphere_mm``), K (3, 3) the intrinsics."""
    out = image
    targets = camera_targets(gaze.centres, np.asarray(K, np.float64), gaze.sphere_mm)
    for e in (0, 1):
        toward = -gaze.centres[e] / np.linalg.norm(gaze.centres[e])
        angle = float(np.degrees(np.arccos(np.clip(gaze.directions[e] @ toward, -1.0, 1.0))))
        s = contact_strength(angle, bool(gaze.closed[e]), options.limit_deg, options.fade_deg)
        if s > 0:
            out = move_iris(out, gaze.lids[e], gaze.irises[e], s * (targets[e] - gaze.irises[e][0, :2]))
    return out
