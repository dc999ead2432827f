"""Corners on the face tied to the fitted mesh and tracked to the next frame (issue 20, seed 003).

The appearance refinement (:mod:`.appearance`) matches the frame to a learned, blurred template
of the person: good for where the face is, weak for how it moved since the last frame. Corners
of the face (eye corners, nostrils, brows, the mouth, skin marks) are tracked from one frame to
the next with pyramidal Lucas-Kanade, the optical-flow constraint on small windows, to a
fraction of a pixel; each corner rides on the mesh (a weighted mean of its three nearest
projected vertices plus a fixed offset), so the tracked corners tell the refinement where those
vertices went.

Arrays in, arrays out: :func:`surface_features` picks and ties the corners in one frame,
:func:`track_features` finds them in the next.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesculpt.geometry.point_bounds import point_bounds

#: Corners picked per frame, at most.
MAX_FEATURES = 150
#: A corner must be this far (px) from the face's projected outline (its window stays on the face).
OUTLINE_MARGIN_PX = 10
#: Lucas-Kanade window (px) and pyramid levels.
WINDOW_PX = 15
LEVELS = 2
#: A corner tracked forward then backward must come back within this distance (px).
FORWARD_BACKWARD_PX = 0.3


@dataclass
class SurfaceFeatures:
    """Corners of one frame: pixels (P, 2) float64; each tied to the mesh by ``vertices`` (P, 3)
    int, ``weights`` (P, 3) (summing to 1) and ``offsets`` (P, 2) px: pixel = weights @ the
    vertices' pixels + offset."""

    pixels: np.ndarray
    vertices: np.ndarray
    weights: np.ndarray
    offsets: np.ndarray

    def __len__(self) -> int:
        return len(self.pixels)


def _face_box(projected: np.ndarray, shape: tuple[int, int], margin: int) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1): the projected vertices' box grown by ``margin`` px, inside the frame."""
    lo, hi = point_bounds(projected)
    lo, hi = np.floor(lo).astype(int) - margin, np.ceil(hi).astype(int) + margin
    h, w = shape
    return max(lo[0], 0), max(lo[1], 0), min(hi[0], w), min(hi[1], h)


def surface_features(grey: np.ndarray, projected: np.ndarray, usable: np.ndarray,
                     max_features: int = MAX_FEATURES, kept: np.ndarray | None = None) -> SurfaceFeatures | None:
    """The corners (Shi-Tomasi) of ``grey`` (H, W) uint8 on the face, tied to the mesh.

    projected: (V, 2) the fitted mesh's vertices in pixels; usable: (V,) bool the vertices the
    frame sees (the face's region is their convex hull, shrunk by OUTLINE_MARGIN_PX, and corners
    tie to them only); kept: (K, 2) px corners tracked into this frame, kept where they are still
    on the face (new ones are only looked for when fewer than half of ``max_features`` are).
    None when the face offers fewer than 10 corners."""
    import cv2  # here: the fitter starts without OpenCV (a respawn's imports)
    idx = np.flatnonzero(usable)
    if len(idx) < 10:
        return None
    px = np.asarray(projected, np.float64)[idx]
    x0, y0, x1, y1 = _face_box(px, grey.shape[:2], 1)
    if x1 - x0 < 16 or y1 - y0 < 16:
        return None
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull((px - [x0, y0]).astype(np.int32)), 255)
    mask = cv2.erode(mask, np.ones((2 * OUTLINE_MARGIN_PX + 1,) * 2, np.uint8))
    pixels = np.zeros((0, 2))
    if kept is not None and len(kept):
        at = np.round(kept - [x0, y0]).astype(int)
        on = (at >= 0).all(axis=1) & (at[:, 0] < mask.shape[1]) & (at[:, 1] < mask.shape[0])
        on[on] = mask[at[on, 1], at[on, 0]] > 0
        pixels = np.asarray(kept, np.float64)[on]
    if len(pixels) < max_features // 2:
        for x, y in np.round(pixels - [x0, y0]).astype(int):   # new corners away from the kept ones
            cv2.circle(mask, (int(x), int(y)), 5, 0, -1)
        corners = cv2.goodFeaturesToTrack(grey[y0:y1, x0:x1], max_features - len(pixels), 0.01, 5, mask=mask)
        if corners is not None:
            pixels = np.vstack([pixels, corners.reshape(-1, 2).astype(np.float64) + [x0, y0]])
    if len(pixels) < 10:
        return None
    # Imported here, not at the top: only refine=appearance comes here, and importing scipy would
    # lengthen every fitter's start-up (a respawned node's time away).
    from scipy.spatial import cKDTree

    # built for one query: an unbalanced tree builds in half the time and finds the same neighbours
    dist, nearest = cKDTree(px, balanced_tree=False, compact_nodes=False).query(pixels, k=3)
    weights = 1.0 / np.maximum(dist, 0.5)
    weights /= weights.sum(axis=1, keepdims=True)
    vertices = idx[nearest]
    offsets = pixels - np.einsum("pk,pkc->pc", weights, np.asarray(projected, np.float64)[vertices])
    return SurfaceFeatures(pixels, vertices, weights, offsets)


def track_features(previous: np.ndarray, grey: np.ndarray,
                   features: SurfaceFeatures) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where ``features`` of the frame ``previous`` (H, W) uint8 are in ``grey`` (H, W) uint8:
    (pixels (P, 2) float64, found (P,) bool: tracked both ways and back within
    FORWARD_BACKWARD_PX, so a corner a hand or a blink covered is not trusted; error (P,) float64
    px: how far the way back missed, a measure of each track's noise). Only the face's box (grown
    by the window and the pyramid's reach) is searched."""
    import cv2  # here: the fitter starts without OpenCV (a respawn's imports)
    reach = WINDOW_PX * 2 ** LEVELS
    x0, y0, x1, y1 = _face_box(features.pixels, grey.shape[:2], reach)
    a, b = previous[y0:y1, x0:x1], grey[y0:y1, x0:x1]
    p0 = (features.pixels - [x0, y0]).astype(np.float32).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.01)
    lk = dict(winSize=(WINDOW_PX, WINDOW_PX), maxLevel=LEVELS, criteria=criteria)
    p1, found, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, None, **lk)
    # back from where each was found, starting where it came from: a consistent track returns
    # there, so the way back needs no pyramid
    back, found_back, _ = cv2.calcOpticalFlowPyrLK(b, a, p1, p0.copy(), winSize=lk["winSize"], maxLevel=0,
                                                   criteria=criteria, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    error = np.linalg.norm((back - p0).reshape(-1, 2), axis=1)
    ok = (found.reshape(-1) == 1) & (found_back.reshape(-1) == 1) & (error < FORWARD_BACKWARD_PX)
    return p1.reshape(-1, 2).astype(np.float64) + [x0, y0], ok, error.astype(np.float64)
