"""The palm detector: its constants (input size, anchor strides, seven keypoints; anchors and
decoding are :mod:`facesculpt.geometry.detections`'), palms after weighted NMS, and the hand
crop (ROI) a palm gives. Arrays in, arrays out.

mediapipe's palm detector (``palm_detection_full``, 192x192 RGB input in [0, 1], the frame
letterboxed) regresses, per anchor, a box (centre offset, width, height) and seven keypoints
in input pixels relative to the anchor centre (0 the wrist centre, 2 the middle finger's
knuckle; the others on the palm and the thumb's base). Its score is a logit.

The hand crop follows mediapipe's palm-to-ROI rule: rotated so the wrist -> middle-knuckle
direction points up the crop, centre shifted half a box height towards the fingers, side 2.6x
the box's longer side. Coordinates are continuous image pixels (pixel i spans [i, i + 1]).
"""

from __future__ import annotations

import math

import numpy as np

from facesculpt.geometry.detections import Detection, merged_detections

PALM_SIZE = 192
NUM_PALM_KEYPOINTS = 7
PALM_WRIST, PALM_MIDDLE_MCP = 0, 2
ANCHOR_STRIDES = (8, 16, 16, 16)
PALM_ROI_SCALE = 2.6
PALM_ROI_SHIFT_Y = -0.5


#: A palm detection in image pixels (continuous): ``box`` (4,) [xmin, ymin, xmax, ymax],
#: ``keypoints`` (7, 2), ``score`` in [0, 1].
Palm = Detection


def weighted_nms(boxes: np.ndarray, keypoints: np.ndarray, scores: np.ndarray,
                 iou_threshold: float = 0.3) -> list[Palm]:
    """:func:`facesculpt.geometry.detections.merged_detections`: weighted NMS as :class:`Palm` objects."""
    return merged_detections(boxes, keypoints, scores, iou_threshold)


def up_angle(base: np.ndarray, tip: np.ndarray) -> float:
    """The crop angle (radians, of the crop's x axis from the image's) that makes ``base`` ->
    ``tip`` (image pixels) point up the crop (towards its smaller y)."""
    d = np.asarray(base, np.float64) - np.asarray(tip, np.float64)  # the crop's +y axis
    return math.atan2(-float(d[0]), float(d[1]))


def transform_roi(centre, width: float, height: float, angle: float, scale: float, shift_y: float) -> np.ndarray:
    """mediapipe's rect transformation: shift the centre by ``shift_y`` heights along the crop's
    y axis, make it square on its longer side, scale. Returns (5,) [cx, cy, side, side, angle]."""
    c, s = math.cos(angle), math.sin(angle)
    shift = shift_y * height
    cx = float(centre[0]) - s * shift
    cy = float(centre[1]) + c * shift
    side = max(width, height) * scale
    return np.array([cx, cy, side, side, angle], np.float64)


def roi_from_palm(palm: Palm) -> np.ndarray:
    """The hand crop (5,) [cx, cy, side, side, angle] of a palm detection (continuous pixels)."""
    angle = up_angle(palm.keypoints[PALM_WRIST], palm.keypoints[PALM_MIDDLE_MCP])
    centre = (palm.box[:2] + palm.box[2:]) / 2.0
    w, h = float(palm.box[2] - palm.box[0]), float(palm.box[3] - palm.box[1])
    return transform_roi(centre, w, h, angle, PALM_ROI_SCALE, PALM_ROI_SHIFT_Y)
