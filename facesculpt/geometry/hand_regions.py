"""The 21 hand landmarks by name, the hand's size, and the image region a hand covers.

Joint order (mediapipe's, as ``hands/landmarks`` carries it): 0 wrist; thumb 1-4, index 5-8,
middle 9-12, ring 13-16, little finger 17-20, each from its base joint to its tip.

:func:`hand_region_mask` is what the renderer keeps from the input so that nothing it
re-renders covers a hand: per finger the convex hull of its joints (each a disc as wide as a
finger), the palm's convex hull (wrist, thumb base and the four knuckles), dilated by a margin.
Pixels: x, y image pixels (OpenCV's convention, pixel centres at integers).
"""

from __future__ import annotations

import cv2
import numpy as np

WRIST = 0
THUMB_TIP = 4
INDEX_MCP, INDEX_TIP = 5, 8
MIDDLE_MCP = 9
PINKY_MCP = 17
FINGERS = ((1, 2, 3, 4), (5, 6, 7, 8), (9, 10, 11, 12), (13, 14, 15, 16), (17, 18, 19, 20))
PALM = (0, 1, 2, 5, 9, 13, 17)
FINGER_WIDTH = 0.24    # a finger's width as a share of the hand size
MARGIN = 0.05          # the dilation of the region as a share of the hand size (plus MARGIN_PX)
MARGIN_PX = 2.0


def hand_size(points: np.ndarray) -> float:
    """A hand's size in pixels from its (21, >=2) points: the larger of the palm's length (wrist to
    middle knuckle) and its width (index to little-finger knuckle), in the image plane."""
    p = np.asarray(points, np.float64)[:, :2]
    return float(max(np.linalg.norm(p[MIDDLE_MCP] - p[WRIST]), np.linalg.norm(p[PINKY_MCP] - p[INDEX_MCP])))


def _disc_hull(points: np.ndarray, radius: float, samples: int = 12) -> np.ndarray:
    """The convex hull (K, 1, 2) int32 of discs of ``radius`` around ``points`` (M, 2)."""
    angles = np.linspace(0.0, 2.0 * np.pi, samples, endpoint=False)
    ring = radius * np.column_stack([np.cos(angles), np.sin(angles)])
    cloud = (points[:, None, :] + ring[None]).reshape(-1, 2)
    return cv2.convexHull(np.round(cloud).astype(np.int32))


def hand_region_mask(hands: np.ndarray, width: int, height: int, margin_px: float | None = None) -> np.ndarray:
    """The (height, width) bool region the hands cover, from ``hands`` (N, 21, >=2) pixels.

    Per hand: the convex hull of each finger's joints and of the palm, each joint widened to a
    disc ``FINGER_WIDTH`` of the hand's size across, dilated by ``margin_px`` (default:
    ``MARGIN`` of the hand's size plus ``MARGIN_PX``). N = 0 gives an empty mask; a hand with
    non-finite points is skipped."""
    mask = np.zeros((int(height), int(width)), np.uint8)
    hands = np.asarray(hands, np.float64)
    for points in hands.reshape(-1, 21, hands.shape[-1]) if hands.size else []:
        p = points[:, :2]
        if not np.isfinite(p).all():
            continue
        size = hand_size(p)
        margin = MARGIN * size + MARGIN_PX if margin_px is None else float(margin_px)
        radius = 0.5 * FINGER_WIDTH * size + max(margin, 0.0)
        for joints in FINGERS:
            cv2.fillConvexPoly(mask, _disc_hull(p[list(joints)], radius), 1)
        cv2.fillConvexPoly(mask, _disc_hull(p[list(PALM)], radius), 1)
    return mask.astype(bool)
