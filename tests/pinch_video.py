"""A test video for pinch input: a shared face video with a real hand composited over it.

The hand is the upper hand of the shared photo ``hands/google_sample_woman_hands.jpg`` (her
right hand, palm to the camera, fingers to the right), cut out of the photo by the hand network's
own landmarks (per finger and palm a convex hull, intersected with the pixels brighter than the
dark backdrop). The photo has no pinch, so its two poses are made from it by moving one rigid
piece, the index finger beyond the middle of its first phalanx:

* **closed**: the piece shortened along the finger and turned so its tip lands on the thumb tip
  (a finger curled toward the camera seen from the front is shorter), drawn under the thumb;
* **open**: the piece lengthened along the finger by ``OPEN_STRETCH``, so the tips part.

:class:`HandSprite` composites a pose at a scale and position; :func:`write_pinch_video`
writes the scripted video (FFV1, lossless) and returns its frames and script.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from benchmarks.realism.sequences import read_video, write_lossless
from facesculpt.geometry.hand_regions import FINGERS, INDEX_MCP, INDEX_TIP, PALM, THUMB_TIP, hand_size

PHOTO = "google_sample_woman_hands.jpg"
BACKDROP_GREY = 70       # the photo's backdrop is darker than this, the hand brighter
HULL_WIDTH = 0.30        # a finger's hull as wide as this share of the hand's size
PIECE_START = 0.5        # the moved piece starts this far from the index knuckle to its next joint
OPEN_STRETCH = 1.25      # the open pose's index finger, this much longer beyond PIECE_START


def _hull(points: np.ndarray, joints, width: float, shape) -> np.ndarray:
    """(H, W) uint8 the convex hull of discs ``width`` px across around ``points[joints]``."""
    angles = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
    ring = 0.5 * width * np.column_stack([np.cos(angles), np.sin(angles)])
    cloud = (points[list(joints)][:, None] + ring[None]).reshape(-1, 2)
    mask = np.zeros(shape[:2], np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull(np.round(cloud).astype(np.int32)), 1)
    return mask


def _over(dst: np.ndarray, img: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    return img * alpha[..., None] + dst * (1.0 - alpha[..., None])


@dataclass
class HandSprite:
    """One pose of the cut-out hand: ``image`` (h, w, 3) float32 BGR and ``alpha`` (h, w)
    float32 0..1 in the photo's pixels; ``anchor`` (2,) the photo's thumb tip, px (both poses
    keep it, and the closed pose pinches there)."""

    image: np.ndarray
    alpha: np.ndarray
    anchor: np.ndarray

    def paste(self, frame: np.ndarray, scale: float, at, angle_deg: float = 0.0, mirror: bool = False) -> np.ndarray:
        """A copy of ``frame`` (H, W, 3) uint8 with the hand mirrored left-right (``mirror``),
        turned by ``angle_deg`` (degrees, clockwise on the screen), scaled by ``scale`` and placed
        so its anchor lands on ``at`` (x, y) px."""
        h, w = frame.shape[:2]
        a = np.deg2rad(angle_deg)
        A = scale * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) @ np.diag([-1.0 if mirror else 1.0, 1.0])
        M = np.hstack([A, (np.asarray(at, np.float64) - A @ self.anchor)[:, None]])
        img = cv2.warpAffine(self.image, M, (w, h), flags=cv2.INTER_AREA)
        alpha = cv2.warpAffine(self.alpha, M, (w, h), flags=cv2.INTER_LINEAR)
        return np.clip(_over(frame.astype(np.float32), img, alpha) + 0.5, 0, 255).astype(np.uint8)


def hand_sprites(photo: np.ndarray, points: np.ndarray) -> tuple[HandSprite, HandSprite]:
    """The (open, closed) poses of the hand whose (21, >=2) landmarks ``points`` the hand
    network found in ``photo`` (H, W, 3) uint8."""
    P = np.asarray(points, np.float64)[:, :2]
    size = hand_size(P)
    shape = photo.shape
    region = np.zeros(shape[:2], np.uint8)
    for joints in (*FINGERS, PALM):
        region |= _hull(P, joints, HULL_WIDTH * size, shape)
    bright = (cv2.cvtColor(photo, cv2.COLOR_BGR2GRAY) > BACKDROP_GREY).astype(np.uint8)
    alpha = cv2.morphologyEx(region & bright, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    alpha = cv2.morphologyEx(alpha, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    thumb = _hull(P, FINGERS[0][1:], HULL_WIDTH * size, shape) & alpha
    middle = _hull(P, FINGERS[2], 0.2 * size, shape)
    axis = (P[INDEX_TIP] - P[INDEX_MCP]) / np.linalg.norm(P[INDEX_TIP] - P[INDEX_MCP])
    base = P[INDEX_MCP] + PIECE_START * (P[INDEX_MCP + 1] - P[INDEX_MCP])
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
    beyond = ((xs - base[0]) * axis[0] + (ys - base[1]) * axis[1] > 0).astype(np.uint8)
    piece = _hull(P, FINGERS[1], 0.27 * size, shape) & alpha & (1 - middle) & beyond
    rest = (alpha & (1 - piece)).astype(np.float32)
    src = photo.astype(np.float32)
    backdrop = np.zeros_like(src)

    def pose(A: np.ndarray, moving: np.ndarray) -> HandSprite:
        """The hand with the ``moving`` pixels moved by the linear map ``A`` about ``base``, under
        the thumb."""
        M = np.hstack([A, (base - A @ base)[:, None]])
        img = cv2.warpAffine(src, M, (shape[1], shape[0]), flags=cv2.INTER_LINEAR)
        a = cv2.warpAffine(moving.astype(np.float32), M, (shape[1], shape[0]), flags=cv2.INTER_LINEAR)
        image = _over(_over(_over(backdrop, src, rest), img, a), src, thumb.astype(np.float32))
        out_alpha = np.clip(np.maximum(np.maximum(rest, a), thumb), 0.0, 1.0)
        return HandSprite(image, out_alpha.astype(np.float32), P[THUMB_TIP].copy())

    stretch = np.eye(2) + (OPEN_STRETCH - 1.0) * np.outer(axis, axis)
    v0, v1 = P[INDEX_TIP] - base, P[THUMB_TIP] - base
    shorten = np.eye(2) + (np.linalg.norm(v1) / np.linalg.norm(v0) - 1.0) * np.outer(axis, axis)
    turn = np.arctan2(v1[1], v1[0]) - np.arctan2(v0[1], v0[0])
    rotate = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    return pose(stretch, piece), pose(rotate @ shorten, piece & (1 - thumb))


@dataclass
class Step:
    """The hand in one frame: ``pose`` "open", "closed" or "" (no hand); ``at`` (x, y) px
    where its anchor (the pinch point when closed) is."""

    pose: str
    at: tuple[float, float]


def pinch_script(start, frames: int, move_px: float) -> list[Step]:
    """The scripted path at 25 frames/s: no hand for 15 frames; the open hand at ``start``
    (17 frames); pinched there (5); pinched, moving right by ``move_px`` (20); pinched, still (5);
    opened, still (5); open, moving on to the right and up by ``2 * move_px`` each over the
    remaining frames (off the nose: the edit shows, and it must not follow the open hand)."""
    x, y = float(start[0]), float(start[1])
    steps = [Step("", (x, y))] * 15 + [Step("open", (x, y))] * 17 + [Step("closed", (x, y))] * 5
    steps += [Step("closed", (x + move_px * (k + 1) / 20, y)) for k in range(20)]
    x1 = x + move_px
    steps += [Step("closed", (x1, y))] * 5 + [Step("open", (x1, y))] * 5
    rest = frames - len(steps)
    steps += [Step("open", (x1 + 2 * move_px * (k + 1) / rest, y - 2 * move_px * (k + 1) / rest)) for k in range(rest)]
    return steps[:frames]


def write_pinch_video(faces: list[np.ndarray], sprites: dict[str, HandSprite], steps: list[Step], scale: float,
                      angle_deg: float, path: Path) -> list[np.ndarray]:
    """The face frames with the hand of each step pasted (``HandSprite.paste`` with ``scale``
    and ``angle_deg``), written to ``path`` (.mkv, FFV1, 25 frames/s); returns the frames."""
    out = [sprites[s.pose].paste(f, scale, s.at, angle_deg) if s.pose else f.copy() for f, s in zip(faces, steps)]
    write_lossless(out, path, fps=25)
    return out


def read_faces(data_dir: Path, name: str = "d0.mp4") -> list[np.ndarray]:
    """Every frame of the shared face video ``name``."""
    return read_video(data_dir / "video" / name)
