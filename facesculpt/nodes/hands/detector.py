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
   end on one hand become one. The loop is :class:`facesculpt.geometry.roi_tracker.RoiTracker`,
   which the face detector shares, and the options
   :class:`~facesculpt.geometry.detector_options.DetectorOptions` (:data:`HAND_OPTIONS`).

Handedness: the network was trained on mirrored (selfie) images; :class:`Hand` reports the
person's own hand in the image as given (``mirrored=False``, a camera that does not flip), or
in a mirrored view (``mirrored=True``).

Coordinates: image pixels with the centre of pixel (i, j) at (x=i, y=j) (OpenCV's convention);
crops use continuous coordinates internally (pixel i spans [i, i + 1]).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from facesculpt.geometry.bgr_image import as_bgr_uint8
from facesculpt.geometry.crops import (
    crop_image,
    crop_to_image,
    letterbox_roi,
    network_input,
    pixel_indices,
    rotated_box,
)
from facesculpt.geometry.detections import decode_ssd, detections_in_image, ssd_anchors
from facesculpt.geometry.detector_options import DetectorOptions
from facesculpt.geometry.roi_tracker import RoiTracker, Track
from facesculpt.networks import load_networks

from .palm import (
    ANCHOR_STRIDES,
    NUM_PALM_KEYPOINTS,
    PALM_SIZE,
    Palm,
    roi_from_palm,
    transform_roi,
    up_angle,
    weighted_nms,
)

__all__ = ["HAND_OPTIONS", "Hand", "HandDetector", "as_bgr", "crop_image", "letterbox_roi", "palm_centre",
           "project_hand", "roi_from_hand"]

HAND_SIZE = 224
NUM_HAND_POINTS = 21
# Joints that place the next crop (wrist, thumb base, and the knuckles of each finger), as
# mediapipe's hand-landmarks-to-rect rule.
_ROI_JOINTS = (0, 1, 2, 3, 5, 6, 9, 10, 13, 14, 17, 18)
WRIST, INDEX_MCP, MIDDLE_MCP, RING_MCP = 0, 5, 9, 13
_TRACK_ROI_SCALE, _TRACK_ROI_SHIFT_Y = 2.0, -0.1
_FILES = ("palm_detector.onnx", "hand_landmark.onnx")
#: The hands detector's options: :class:`DetectorOptions` with two hands, the palm detector every
#: 10 frames while fewer are tracked (``max_hands`` is ``max_tracked``).
HAND_OPTIONS = DetectorOptions(max_tracked=2, redetect_interval=10)
HAND_ALIASES = {"max_hands": "max_tracked"}


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
def project_hand(raw: np.ndarray, roi: np.ndarray, size: int = HAND_SIZE) -> np.ndarray:
    """Network points (21, 3) in crop pixels -> (21, 3) image pixels (continuous; z scaled like x)."""
    return crop_to_image(raw, roi, size)


def roi_from_hand(points_xy: np.ndarray) -> np.ndarray:
    """The next crop (5,) from a hand's points (21, 2) (continuous pixels)."""
    knuckles = (points_xy[INDEX_MCP] + points_xy[RING_MCP]) / 2.0
    knuckles = (knuckles + points_xy[MIDDLE_MCP]) / 2.0
    angle = up_angle(points_xy[WRIST], knuckles)
    centre, w, h = rotated_box(points_xy[list(_ROI_JOINTS)], angle)
    return transform_roi(centre, w, h, angle, _TRACK_ROI_SCALE, _TRACK_ROI_SHIFT_Y)


def palm_centre(points_xy: np.ndarray) -> np.ndarray:
    """Mean of the wrist and the four finger knuckles, (2,)."""
    return points_xy[[0, 5, 9, 13, 17]].mean(axis=0)


def as_bgr(image) -> np.ndarray | None:
    """(H, W, 3) uint8 BGR from a BGR, BGRA or grey uint8 image; None for anything else."""
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8:
        return None
    return as_bgr_uint8(image)


class HandDetector(RoiTracker):
    """Palm detector + 21-point hand landmarks with ROI tracking (:class:`RoiTracker`), up to
    ``max_hands`` hands.

    Options (:class:`DetectorOptions`; ``options`` replaces :data:`HAND_OPTIONS`, keyword
    arguments replace single fields; ``max_hands`` is ``max_tracked``): models_dir, the directory
    `facesculpt setup` filled (default :func:`model_home`; a missing file raises
    :class:`MissingModelsError` naming `facesculpt setup`); threads, onnxruntime intra-op threads;
    min_detection_score, palm score threshold; min_tracking_score, hand presence below which a
    hand counts as lost; nms_iou, palm NMS overlap; redetect_interval, frames between
    palm-detector runs while fewer than ``max_hands`` are tracked; mirrored, the images are
    mirrored (a selfie view), for handedness; backend, "onnxruntime" (the converted networks) or
    "litert" (the original .tflite ones, a reference).

    ``detect(image)`` always runs the palm detector; ``track(image)`` reuses the last crops.
    Both return a list of :class:`Hand` (empty when none) and never raise on bad images.
    """

    crop_size = HAND_SIZE
    keep_largest = False
    defaults, aliases = HAND_OPTIONS, HAND_ALIASES
    max_hands = RoiTracker.max_tracked  # this detector's name for it

    def load(self, options: DetectorOptions) -> None:
        self.palm_net, self.hand_net = load_networks(options.models_dir, _FILES, options.backend, options.threads,
                                                     "hand")
        self.mirrored = bool(options.mirrored)
        self.anchors = ssd_anchors(PALM_SIZE, ANCHOR_STRIDES)

    # ---- the steps the loop calls --------------------------------------------------------------
    def prepare(self, image) -> np.ndarray | None:
        """:func:`as_bgr`: uint8 images only."""
        return as_bgr(image)

    def run_detector(self, bgr: np.ndarray) -> list[Palm]:
        """Every palm in a BGR uint8 image (continuous pixels), best first."""
        h, w = bgr.shape[:2]
        roi = letterbox_roi(w, h)
        x = network_input(bgr, roi, PALM_SIZE, border=cv2.BORDER_CONSTANT)
        raw_boxes, raw_scores = self.palm_net.run(x)
        boxes, keypoints, scores = decode_ssd(raw_boxes[0], raw_scores[0, :, 0], self.anchors, PALM_SIZE,
                                             NUM_PALM_KEYPOINTS, self.min_detection_score)
        if not len(scores):
            return []
        detections = detections_in_image(boxes, keypoints, scores, roi[0] - roi[2] / 2.0, roi[1] - roi[3] / 2.0,
                                         roi[2])
        return weighted_nms(*detections, self.nms_iou)

    def run_palm_detector(self, bgr: np.ndarray) -> list[Palm]:
        """Deprecated name of :meth:`run_detector` (warns once)."""
        global _WARNED_PALM
        if not _WARNED_PALM:
            _WARNED_PALM = True
            warnings.warn("HandDetector.run_palm_detector is deprecated: call run_detector",
                          DeprecationWarning, stacklevel=2)
        return self.run_detector(bgr)

    def detection_roi(self, detection: Palm) -> np.ndarray:
        return roi_from_palm(detection)

    def run_landmarks(self, x: np.ndarray) -> tuple[np.ndarray, float, float]:
        raw_points, presence, handedness, _world = self.hand_net.run(x)
        # The network's handedness score is mediapipe's "Left" in a mirrored (selfie) view, which
        # is the person's right hand in the image as the camera saw it.
        right = float(handedness.reshape(-1)[0])
        right = 1.0 - right if self.mirrored else right
        return raw_points.reshape(NUM_HAND_POINTS, 3).astype(np.float64), float(presence.reshape(-1)[0]), right

    def landmarks_roi(self, points_xy: np.ndarray) -> np.ndarray:
        return roi_from_hand(points_xy)

    def anchor(self, points: np.ndarray) -> np.ndarray:
        """The palm's centre (:func:`palm_centre`)."""
        return palm_centre(points[:, :2])

    def same(self, a: Track, b: Track) -> bool:
        """Two tracks on one hand: palm centres closer than half the larger palm (wrist -> middle knuckle)."""
        pa, pb = a.points[:, :2], b.points[:, :2]
        palm = max(np.linalg.norm(pa[MIDDLE_MCP] - pa[WRIST]), np.linalg.norm(pb[MIDDLE_MCP] - pb[WRIST]))
        return bool(np.linalg.norm(palm_centre(pa) - palm_centre(pb)) < 0.5 * palm)

    def results(self) -> list[Hand]:
        """The tracked hands in track-id order, in pixel indices."""
        out = []
        for t in sorted(self._tracks, key=lambda t: t.track_id):
            points, roi = pixel_indices(t.points, t.crop_roi)
            out.append(Hand(points=points, score=t.score, right=t.label, roi=roi, track_id=t.track_id))
        return out


_WARNED_PALM = False
