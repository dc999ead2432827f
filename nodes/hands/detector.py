"""Hands: palm detection and 21-point hand landmarks on onnxruntime, with ROI tracking.

The pipeline follows mediapipe's hand-tracking graph, written out here:

1. **Palm detector** (:mod:`.palm`): the whole frame letterboxed into 192x192 RGB in [0, 1];
   palms scoring at least ``min_detection_score`` after weighted NMS; each gives a rotated
   square crop (wrist -> middle knuckle pointing up, 2.6x the palm box).
2. **Hand landmarks** (224x224 crop, RGB in [0, 1]): 21 points (x, y in crop pixels, z depth
   relative to the wrist in the same scale), a hand-presence score and a handedness score (both
   already probabilities). The points are mapped back through the crop: x, y image pixels, z
   scaled like x (smaller = nearer the camera).
3. **Tracking**: the next frame's crop comes from the last points (wrist -> the knuckles'
   weighted centre pointing up; the box of the wrist, thumb and knuckle joints in that rotated
   frame, shifted a tenth of its height towards the fingers, 2x its longer side); the palm
   detector runs again when a hand is lost (presence below ``min_tracking_score``) or, while
   fewer than ``max_hands`` are tracked, every ``redetect_interval`` frames. Two crops that
   end on one hand become one.

Handedness: the network was trained on mirrored (selfie) images; :class:`Hand` reports the
person's own hand in the image as given (``mirrored=False``, a camera that does not flip), or
in a mirrored view (``mirrored=True``).

Coordinates: image pixels with the centre of pixel (i, j) at (x=i, y=j) (OpenCV's convention);
crops use continuous coordinates internally (pixel i spans [i, i + 1]).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from facesculpt.geometry.crops import crop_image, rotation_2d
from facesculpt.geometry.detections import decode_ssd, ssd_anchors
from facesculpt.networks import LiteRtNetwork, OnnxNetwork
from facesculpt.paths import MissingModelsError, model_home

from .palm import ANCHOR_STRIDES, NUM_PALM_KEYPOINTS, PALM_SIZE, roi_from_palm, transform_roi, up_angle, weighted_nms

HAND_SIZE = 224
NUM_HAND_POINTS = 21
# Joints that place the next crop (wrist, thumb base, and the knuckles of each finger), as
# mediapipe's hand-landmarks-to-rect rule.
_ROI_JOINTS = (0, 1, 2, 3, 5, 6, 9, 10, 13, 14, 17, 18)
WRIST, INDEX_MCP, MIDDLE_MCP, RING_MCP = 0, 5, 9, 13
_TRACK_ROI_SCALE, _TRACK_ROI_SHIFT_Y = 2.0, -0.1
_FILES = ("palm_detector.onnx", "hand_landmark.onnx")


@dataclass
class Hand:
    """One hand: ``points`` (21, 3) float32 (x, y image pixels, z depth relative to the wrist in
    pixel scale; mediapipe's joint order: 0 wrist, 1-4 thumb, 5-8 index, 9-12 middle, 13-16 ring,
    17-20 little finger, base to tip), ``score`` hand presence in [0, 1], ``right`` the
    probability that it is the person's right hand, ``roi`` (5,) float32 [cx, cy, w, h,
    angle_rad] of the crop the points came from, ``track_id`` the same number for the same
    tracked hand from frame to frame (0, 1, ... in the order first found)."""

    points: np.ndarray
    score: float
    right: float
    roi: np.ndarray
    track_id: int = 0

    @property
    def handedness(self) -> str:
        """"right" or "left" (the person's)."""
        return "right" if self.right >= 0.5 else "left"


# ---------------------------------------------------------------------------------------------
# Crops
# ---------------------------------------------------------------------------------------------
def letterbox_roi(width: int, height: int) -> np.ndarray:
    """The square ROI that letterboxes a whole (width, height) frame (centred, black bars)."""
    side = float(max(width, height))
    return np.array([width / 2.0, height / 2.0, side, side, 0.0])


def project_hand(raw: np.ndarray, roi: np.ndarray, size: int = HAND_SIZE) -> np.ndarray:
    """Network points (21, 3) in crop pixels -> (21, 3) image pixels (continuous; z scaled like x)."""
    cx, cy, w, h, angle = (float(v) for v in roi)
    local = (raw[:, :2] / size - 0.5) * np.array([w, h])
    xy = local @ rotation_2d(angle).T + np.array([cx, cy])
    return np.hstack([xy, raw[:, 2:3] / size * w])


def roi_from_hand(points_xy: np.ndarray) -> np.ndarray:
    """The next crop (5,) from a hand's points (21, 2) (continuous pixels)."""
    knuckles = (points_xy[INDEX_MCP] + points_xy[RING_MCP]) / 2.0
    knuckles = (knuckles + points_xy[MIDDLE_MCP]) / 2.0
    angle = up_angle(points_xy[WRIST], knuckles)
    rot = rotation_2d(angle)
    local = points_xy[list(_ROI_JOINTS)] @ rot  # along the crop's x and y axes
    lo, hi = local.min(0), local.max(0)
    centre = rot @ ((lo + hi) / 2.0)
    w, h = (float(v) for v in (hi - lo))
    return transform_roi(centre, w, h, angle, _TRACK_ROI_SCALE, _TRACK_ROI_SHIFT_Y)


def palm_centre(points_xy: np.ndarray) -> np.ndarray:
    """Mean of the wrist and the four finger knuckles, (2,)."""
    return points_xy[[0, 5, 9, 13, 17]].mean(axis=0)


def as_bgr(image) -> np.ndarray | None:
    """(H, W, 3) uint8 BGR from a BGR, BGRA or grey uint8 image; None for anything else."""
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.size == 0:
        return None
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.ndim == 3 and image.shape[2] in (3, 4):
        return np.ascontiguousarray(image[:, :, :3])
    return None


@dataclass
class _Track:
    """A tracked hand, continuous coordinates."""

    crop_roi: np.ndarray
    points: np.ndarray
    score: float
    right: float
    next_roi: np.ndarray
    track_id: int = -1


class HandDetector:
    """Palm detector + 21-point hand landmarks with ROI tracking, up to ``max_hands`` hands.

    models_dir: the directory `facesculpt setup` filled (default :func:`model_home`); a missing
    file raises :class:`MissingModelsError` naming `facesculpt setup`. threads: onnxruntime
    intra-op threads. min_detection_score: palm score threshold; min_tracking_score: hand
    presence below which a hand counts as lost; nms_iou: palm NMS overlap;
    redetect_interval: frames between palm-detector runs while fewer than ``max_hands`` are
    tracked; mirrored: the images are mirrored (a selfie view), for handedness; backend:
    "onnxruntime" (the converted networks) or "litert" (the original .tflite ones, a reference).

    ``detect(image)`` always runs the palm detector; ``track(image)`` reuses the last crops.
    Both return a list of :class:`Hand` (empty when none) and never raise on bad images.
    """

    def __init__(self, models_dir: str | Path | None = None, threads: int = 1, max_hands: int = 2,
                 min_detection_score: float = 0.5, min_tracking_score: float = 0.5, nms_iou: float = 0.3,
                 redetect_interval: int = 10, mirrored: bool = False, backend: str = "onnxruntime"):
        home = Path(models_dir) if models_dir is not None else model_home()
        ext = {"onnxruntime": ".onnx", "litert": ".tflite"}.get(backend)
        if ext is None:
            raise ValueError(f"unknown backend {backend!r} (onnxruntime or litert)")
        paths = [home / name.replace(".onnx", ext) for name in _FILES]
        for path in paths:
            if not path.is_file():
                raise MissingModelsError(
                    f"{path} is missing: run `facesculpt setup` to fetch and convert the hand networks "
                    f"(or point FACESCULPT_HOME / models_dir at the directory where it put them)")
        network = OnnxNetwork if backend == "onnxruntime" else LiteRtNetwork
        self.palm_net, self.hand_net = (network(p, threads) for p in paths)
        self.max_hands = max(int(max_hands), 1)
        self.min_detection_score = float(min_detection_score)
        self.min_tracking_score = float(min_tracking_score)
        self.nms_iou = float(nms_iou)
        self.redetect_interval = max(int(redetect_interval), 1)
        self.mirrored = bool(mirrored)
        self.anchors = ssd_anchors(PALM_SIZE, ANCHOR_STRIDES)
        self._tracks: list[_Track] = []
        self._next_track_id = 0
        self._frames_since_detect = 0
        self.last_ran_detector = False

    def reset(self) -> None:
        """Forget the tracked hands; track ids start again from 0."""
        self._tracks = []
        self._next_track_id = 0

    def detect(self, image) -> list[Hand]:
        """Run the palm detector, then the landmarks on each hand found (a still image)."""
        bgr = as_bgr(image)
        if bgr is None:
            self._tracks = []
            return []
        self._next_track_id = 0
        self._tracks = self._detect_tracks(bgr, [])
        self._frames_since_detect = 0
        self.last_ran_detector = True
        return self._hands()

    def track(self, image) -> list[Hand]:
        """Landmarks from the last crops; the palm detector reruns when a hand is lost or, while
        fewer than ``max_hands`` are tracked, every ``redetect_interval`` frames."""
        bgr = as_bgr(image)
        if bgr is None:
            self._tracks = []
            return []
        self.last_ran_detector = False
        tracks: list[_Track] = []
        for old in self._tracks:
            track = self._refine(bgr, old.next_roi)
            if track is not None and not any(_same_hand(track, t) for t in tracks):
                track.track_id = old.track_id
                tracks.append(track)
        lost = len(tracks) < len(self._tracks)
        self._frames_since_detect += 1
        if not tracks or lost or (len(tracks) < self.max_hands
                                  and self._frames_since_detect >= self.redetect_interval):
            tracks = self._detect_tracks(bgr, tracks)
            self._frames_since_detect = 0
            self.last_ran_detector = True
        self._tracks = tracks
        return self._hands()

    # ---- steps ---------------------------------------------------------------------------
    def run_palm_detector(self, bgr: np.ndarray) -> list:
        """Every palm in a BGR uint8 image (continuous pixels), best first."""
        h, w = bgr.shape[:2]
        roi = letterbox_roi(w, h)
        patch = crop_image(bgr, roi, PALM_SIZE, cv2.BORDER_CONSTANT)
        x = (patch[:, :, ::-1].astype(np.float32) * (1.0 / 255.0))[None]
        raw_boxes, raw_scores = self.palm_net.run(x)
        boxes, keypoints, scores = decode_ssd(raw_boxes[0], raw_scores[0, :, 0], self.anchors, PALM_SIZE,
                                             NUM_PALM_KEYPOINTS, self.min_detection_score)
        if not len(scores):
            return []
        x0, y0, side = roi[0] - roi[2] / 2.0, roi[1] - roi[3] / 2.0, roi[2]
        boxes = boxes * side + np.array([x0, y0, x0, y0], np.float32)
        keypoints = keypoints * side + np.array([x0, y0], np.float32)
        return weighted_nms(boxes, keypoints, scores, self.nms_iou)

    def _refine(self, bgr: np.ndarray, roi: np.ndarray) -> _Track | None:
        """Landmarks on one crop; None when the hand presence is below ``min_tracking_score``."""
        if not (np.all(np.isfinite(roi)) and roi[2] >= 4.0):
            return None
        crop = crop_image(bgr, roi, HAND_SIZE)
        x = (crop[:, :, ::-1].astype(np.float32) * (1.0 / 255.0))[None]
        raw_points, presence, handedness, _world = self.hand_net.run(x)
        score = float(presence.reshape(-1)[0])
        if score < self.min_tracking_score:
            return None
        points = project_hand(raw_points.reshape(NUM_HAND_POINTS, 3).astype(np.float64), roi)
        # The network's handedness score is mediapipe's "Left" in a mirrored (selfie) view, which
        # is the person's right hand in the image as the camera saw it.
        right = float(handedness.reshape(-1)[0])
        right = 1.0 - right if self.mirrored else right
        return _Track(crop_roi=roi, points=points, score=score, right=right, next_roi=roi_from_hand(points[:, :2]))

    def _detect_tracks(self, bgr: np.ndarray, tracks: list[_Track]) -> list[_Track]:
        """Add hands from the palm detector to the tracked ones, up to ``max_hands``."""
        found: list[_Track] = []
        for palm in self.run_palm_detector(bgr):
            if len(tracks) + len(found) >= self.max_hands:
                break
            roi = roi_from_palm(palm)
            if any(_inside(palm_centre(t.points[:, :2]), roi) for t in tracks + found):
                continue
            track = self._refine(bgr, roi)
            if track is not None:
                # Refined once more from its own points: palm boxes are coarse, and a still
                # image has no next frame to correct the crop.
                track = self._refine(bgr, track.next_roi) or track
            if track is not None and not any(_same_hand(track, t) for t in tracks + found):
                found.append(track)
        for track in sorted(found, key=lambda t: t.next_roi[0]):  # new hands numbered left to right
            track.track_id = self._next_track_id
            self._next_track_id += 1
        return tracks + found

    def _hands(self) -> list[Hand]:
        out = []
        for t in sorted(self._tracks, key=lambda t: t.track_id):
            points = t.points.astype(np.float32)
            points[:, :2] -= 0.5
            roi = t.crop_roi.astype(np.float32)
            roi[:2] -= 0.5
            out.append(Hand(points=points, score=t.score, right=t.right, roi=roi, track_id=t.track_id))
        return out


def _inside(point: np.ndarray, roi: np.ndarray) -> bool:
    """True when ``point`` lies inside the central half of the rotated ``roi``."""
    local = (point - roi[:2]) @ rotation_2d(float(roi[4]))
    return bool(np.all(np.abs(local) < roi[2:4] / 4.0))


def _same_hand(a: _Track, b: _Track) -> bool:
    """Two tracks on one hand: palm centres closer than half the larger palm (wrist -> middle knuckle)."""
    pa, pb = a.points[:, :2], b.points[:, :2]
    palm = max(np.linalg.norm(pa[MIDDLE_MCP] - pa[WRIST]), np.linalg.norm(pb[MIDDLE_MCP] - pb[WRIST]))
    return bool(np.linalg.norm(palm_centre(pa) - palm_centre(pb)) < 0.5 * palm)
