"""Face detection and 468-point face-mesh landmarks on onnxruntime, with ROI tracking.

The pipeline follows mediapipe's face-mesh graph, written out here:

1. **Detector** (short range, 128x128 input, RGB in [-1, 1]): 896 SSD anchors on 16x16 and
   8x8 grids; each anchor regresses a box and six keypoints (right eye, left eye, nose tip,
   mouth, right and left ear tragion; "right" is the person's right, image left). Scores pass
   a sigmoid; overlapping boxes merge by *weighted* non-maximum suppression (score-weighted
   mean of each cluster, as mediapipe does). The short-range model sees faces of roughly 15 to
   75 % of its input, so small faces in wide frames are found by also running it on
   overlapping square tiles of decreasing size (:func:`detection_tiles`).
2. **ROI**: a square, rotated crop around the face: centre of the box, side 1.5x the longer
   box side, rotation from the eye line (right eye -> left eye).
3. **Face mesh** (192x192 crop, RGB in [0, 1]): 468 points (x, y in crop pixels, z relative
   depth in the same scale) and a face-presence logit. The points are mapped back through the
   crop: x, y in image pixels, z scaled like x (pixels; smaller = nearer the camera).
4. **Tracking**: the next frame's ROI comes from the last points (rotation from the outer eye
   corners 33 -> 263, box of all points in that rotated frame, side 1.5x); the detector runs
   again only when a face's presence score drops below ``min_tracking_score`` or fewer than
   ``max_faces`` faces are tracked. The loop is :class:`facesculpt.geometry.roi_tracker.RoiTracker`,
   which the hands detector shares, and the options :class:`~facesculpt.geometry.detector_options.DetectorOptions`.

Coordinates: image pixels with the centre of pixel (i, j) at (x=i, y=j) (OpenCV's convention).
Internally crops use continuous coordinates (pixel i spans [i, i+1]); the conversion is done
once where results leave this module.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np

from facesculpt.geometry.bgr_image import as_bgr_uint8
from facesculpt.geometry.crops import crop_image, crop_to_image, network_input, pixel_indices, rotated_box
from facesculpt.geometry.detections import (
    Detection,
    decode_ssd,
    detections_in_image,
    merged_detections,
    ssd_anchors,
)
from facesculpt.geometry.detector_options import DetectorOptions
from facesculpt.geometry.roi_tracker import RoiTracker, Track, sigmoid
from facesculpt.networks import load_networks

log = logging.getLogger(__name__)

__all__ = ["Detection", "Face", "LandmarkDetector", "as_bgr_uint8", "crop_image", "detection_tiles", "project_points",
           "roi_from_detection", "roi_from_points", "weighted_nms"]

DETECTOR_SIZE = 128
MESH_SIZE = 192
NUM_POINTS = 468
NUM_KEYPOINTS = 6
# Mesh points that define the ROI rotation when tracking: outer eye corners (person's right,
# image left -> person's left, image right).
RIGHT_EYE_OUTER, LEFT_EYE_OUTER = 33, 263
NOSE_TIP = 1
ROI_SCALE = 1.5
# Short-range detector anchors (mediapipe SsdAnchorsCalculator options of the model).
_ANCHOR_STRIDES = (8, 16, 16, 16)
_MIN_FACE_IN_TILE = 0.15  # smallest face, as a fraction of a detector tile, to rely on
_DETECTOR_FILES = ("face_detector.onnx", "face_landmark.onnx")
#: The face detector's options (:class:`DetectorOptions`' own defaults; ``max_faces`` is ``max_tracked``).
FACE_OPTIONS = DetectorOptions()
FACE_ALIASES = {"max_faces": "max_tracked"}


@dataclass
class Face:
    """One face: ``points`` (468, 3) float32 (x, y image pixels, z relative depth in pixel
    scale), ``score`` face presence in [0, 1], ``roi`` (5,) float32 [cx, cy, w, h, angle_rad]
    of the crop the points came from (angle: rotation of the crop's x axis from the image's),
    ``track_id`` the same number for the same tracked face from frame to frame (0, 1, ... in the
    order faces are first found, left to right among those found together)."""

    points: np.ndarray
    score: float
    roi: np.ndarray
    track_id: int = 0


# ---------------------------------------------------------------------------------------------
# Detector: weighted NMS, tiles
# ---------------------------------------------------------------------------------------------
def weighted_nms(boxes: np.ndarray, keypoints: np.ndarray, scores: np.ndarray,
                 iou_threshold: float = 0.3) -> list[Detection]:
    """:func:`facesculpt.geometry.detections.merged_detections`: weighted NMS as :class:`Detection` objects."""
    return merged_detections(boxes, keypoints, scores, iou_threshold)


def detection_tiles(width: int, height: int, min_face: float) -> list[tuple[float, float, float]]:
    """Square regions (x0, y0, side) in pixels on which to run the 128x128 detector.

    The first is the whole image, letterboxed (centred, padded with black). Then come levels of
    overlapping tiles (stride half the side) whose side halves from the image's short side until
    a face of ``min_face`` pixels fills at least 15 % of a tile (the short-range model misses
    faces much smaller than that share of its input). ``min_face`` <= 0: the whole image only.
    """
    long_side, short_side = max(width, height), min(width, height)
    tiles = [((width - long_side) / 2.0, (height - long_side) / 2.0, float(long_side))]
    if min_face <= 0:
        return tiles
    side = float(short_side)
    if side > long_side / 1.25:  # almost square: the letterboxed view already is this level
        side /= 2.0
    while side >= 32 and min_face < _MIN_FACE_IN_TILE * tiles[-1][2]:
        stride = side / 2.0
        nx = max(1, int(math.ceil((width - side) / stride)) + 1)
        ny = max(1, int(math.ceil((height - side) / stride)) + 1)
        xs = np.linspace(0.0, max(width - side, 0.0), nx)
        ys = np.linspace(0.0, max(height - side, 0.0), ny)
        tiles.extend((float(x), float(y), side) for y in ys for x in xs)
        side /= 2.0
    return tiles


# ---------------------------------------------------------------------------------------------
# Regions of interest and crops
# ---------------------------------------------------------------------------------------------
def roi_from_detection(det: Detection, scale: float = ROI_SCALE) -> np.ndarray:
    """Crop ROI (5,) [cx, cy, side, side, angle] from a detection (continuous pixels)."""
    centre = (det.box[:2] + det.box[2:]) / 2.0
    side = float(max(det.box[2] - det.box[0], det.box[3] - det.box[1])) * scale
    eye = det.keypoints[1] - det.keypoints[0]  # right eye -> left eye
    angle = math.atan2(float(eye[1]), float(eye[0]))
    return np.array([centre[0], centre[1], side, side, angle], np.float64)


def roi_from_points(points_xy: np.ndarray, scale: float = ROI_SCALE) -> np.ndarray:
    """Crop ROI from mesh points (468, 2) (continuous pixels): rotation from the outer eye
    corners, square box around all points in that rotated frame, side ``scale`` x larger."""
    eye = points_xy[LEFT_EYE_OUTER] - points_xy[RIGHT_EYE_OUTER]
    angle = math.atan2(float(eye[1]), float(eye[0]))
    centre, w, h = rotated_box(points_xy, angle)
    side = max(w, h) * scale
    return np.array([centre[0], centre[1], side, side, angle], np.float64)


def project_points(raw: np.ndarray, roi: np.ndarray, size: int = MESH_SIZE) -> np.ndarray:
    """Mesh output (468, 3) in crop pixels -> (468, 3) image pixels (continuous; z scaled like x)."""
    return crop_to_image(raw, roi, size)


class LandmarkDetector(RoiTracker):
    """Face detector + 468-point face mesh with ROI tracking (:class:`RoiTracker`).

    Options (:class:`DetectorOptions`; ``options`` replaces :data:`FACE_OPTIONS`, keyword
    arguments replace single fields; ``max_faces`` is ``max_tracked``): models_dir, the directory
    `facesculpt setup` filled (default :func:`model_home`; a missing file raises
    :class:`MissingModelsError` naming `facesculpt setup`); threads, onnxruntime intra-op threads;
    max_faces, how many faces to return (the largest first); min_face, the smallest face the
    detector looks for (detector box side, as a fraction of the image's short side; smaller faces
    need more tiles, see :func:`detection_tiles`), 0 = whole image only; min_detection_score,
    nms_iou, detector thresholds; min_tracking_score, face presence below which a face counts as
    lost; redetect_interval, frames between detector runs while fewer than ``max_faces`` faces are
    tracked; backend, "onnxruntime" (the converted networks) or "litert" (the original .tflite
    networks on ai-edge-litert, a reference for tests and benchmarks).

    ``detect(image)`` always runs the detector; ``track(image)`` reuses the last crops and runs
    the detector only when needed. Both return a list of :class:`Face` (empty when none) and
    never raise on bad images.
    """

    crop_size = MESH_SIZE
    keep_largest = True
    defaults, aliases = FACE_OPTIONS, FACE_ALIASES
    max_faces = RoiTracker.max_tracked  # this detector's name for it

    def load(self, options: DetectorOptions) -> None:
        self.detector_net, self.mesh_net = load_networks(options.models_dir, _DETECTOR_FILES, options.backend,
                                                         options.threads, "face")
        self.min_face = max(float(options.min_face), 0.0)
        self.anchors = ssd_anchors(DETECTOR_SIZE, _ANCHOR_STRIDES)

    # ---- the steps the loop calls --------------------------------------------------------------
    def run_detector(self, bgr: np.ndarray) -> list[Detection]:
        """All detections in a BGR uint8 image (continuous pixels), merged over tiles."""
        h, w = bgr.shape[:2]
        min_face = self.min_face * min(w, h)
        boxes, keypoints, scores = [], [], []
        for i, (x0, y0, side) in enumerate(detection_tiles(w, h, min_face)):
            x = network_input(bgr, np.array([x0 + side / 2, y0 + side / 2, side, side, 0.0]), DETECTOR_SIZE,
                              low=-1.0, border=cv2.BORDER_CONSTANT)
            raw_boxes, raw_scores = self.detector_net.run(x)
            b, k, s = decode_ssd(raw_boxes[0], raw_scores[0, :, 0], self.anchors, DETECTOR_SIZE, NUM_KEYPOINTS,
                                 self.min_detection_score)
            if i > 0 and len(s):
                keep = _owned_by_tile(b, x0 / side, y0 / side, w / side, h / side)
                b, k, s = b[keep], k[keep], s[keep]
            if len(s):
                b, k, s = detections_in_image(b, k, s, x0, y0, side)
                boxes.append(b)
                keypoints.append(k)
                scores.append(s)
        if not scores:
            return []
        return weighted_nms(np.concatenate(boxes), np.concatenate(keypoints), np.concatenate(scores),
                            self.nms_iou)

    def detection_roi(self, detection: Detection) -> np.ndarray:
        return roi_from_detection(detection)

    def run_landmarks(self, x: np.ndarray) -> tuple[np.ndarray, float, float]:
        raw_points, raw_score = self.mesh_net.run(x)
        return raw_points.reshape(NUM_POINTS, 3).astype(np.float64), sigmoid(raw_score.reshape(-1)[0]), 0.0

    def landmarks_roi(self, points_xy: np.ndarray) -> np.ndarray:
        return roi_from_points(points_xy)

    def anchor(self, points: np.ndarray) -> np.ndarray:
        """The nose tip (mesh point 1)."""
        return points[NOSE_TIP, :2]

    def results(self) -> list[Face]:
        """The tracked faces, the largest first, at most ``max_faces``, in pixel indices."""
        tracks = sorted(self._tracks, key=lambda t: -t.next_roi[2])[: self.max_faces]
        return [_face(t) for t in tracks]


def _face(track: Track) -> Face:
    points, roi = pixel_indices(track.points, track.crop_roi)
    return Face(points=points, score=float(track.score), roi=roi, track_id=int(track.track_id))


def _owned_by_tile(boxes: np.ndarray, x0: float, y0: float, width: float, height: float) -> np.ndarray:
    """Which detections (normalised boxes (N, 4) in a tile) the tile is responsible for.

    Tiles of a level overlap by half, so the central halves of the tiles cover the image (up to
    its border). A tile keeps faces whose centre lies in its central half (or beyond it towards
    an image border) and that are at most half the tile's side: a face cut by the tile's edge
    is found whole by a neighbour, a bigger face by a coarser level. Tile position and image
    size are in tile sides.
    """
    centre = (boxes[:, :2] + boxes[:, 2:]) / 2.0
    size = np.max(boxes[:, 2:] - boxes[:, :2], axis=1)
    lo = np.array([0.25 if x0 > 1e-6 else -np.inf, 0.25 if y0 > 1e-6 else -np.inf])
    hi = np.array([0.75 if x0 + 1.0 < width - 1e-6 else np.inf, 0.75 if y0 + 1.0 < height - 1e-6 else np.inf])
    return np.all((centre >= lo) & (centre < hi), axis=1) & (size <= 0.5)
