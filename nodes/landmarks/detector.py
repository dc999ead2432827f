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
   ``max_faces`` faces are tracked.

Coordinates: image pixels with the centre of pixel (i, j) at (x=i, y=j) (OpenCV's convention).
Internally crops use continuous coordinates (pixel i spans [i, i+1]); the conversion is done
once where results leave this module.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from facesculpt.geometry.crops import crop_image, rotation_2d
from facesculpt.geometry.detections import decode_ssd, ssd_anchors
from facesculpt.geometry.detections import weighted_nms as nms
from facesculpt.networks import LiteRtNetwork, OnnxNetwork
from facesculpt.paths import MissingModelsError, model_home

log = logging.getLogger(__name__)

DETECTOR_SIZE = 128
MESH_SIZE = 192
NUM_POINTS = 468
NUM_KEYPOINTS = 6
# Mesh points that define the ROI rotation when tracking: outer eye corners (person's right,
# image left -> person's left, image right).
RIGHT_EYE_OUTER, LEFT_EYE_OUTER = 33, 263
ROI_SCALE = 1.5
# Short-range detector anchors (mediapipe SsdAnchorsCalculator options of the model).
_ANCHOR_STRIDES = (8, 16, 16, 16)
_MIN_FACE_IN_TILE = 0.15  # smallest face, as a fraction of a detector tile, to rely on
_DETECTOR_FILES = ("face_detector.onnx", "face_landmark.onnx")


@dataclass
class Detection:
    """A detector result in image pixels (continuous coordinates).

    box: (4,) float32 [xmin, ymin, xmax, ymax]; keypoints: (6, 2) float32; score in [0, 1].
    """

    box: np.ndarray
    keypoints: np.ndarray
    score: float


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
    """:func:`facesculpt.geometry.detections.weighted_nms` as :class:`Detection` objects, best first."""
    return [Detection(box=b, keypoints=k, score=sc) for b, k, sc in nms(boxes, keypoints, scores, iou_threshold)]


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
    rot = rotation_2d(angle)
    local = points_xy @ rot  # coordinates along the crop's x and y axes
    lo, hi = local.min(0), local.max(0)
    centre = rot @ ((lo + hi) / 2.0)
    side = float(max(hi - lo)) * scale
    return np.array([centre[0], centre[1], side, side, angle], np.float64)


def project_points(raw: np.ndarray, roi: np.ndarray, size: int = MESH_SIZE) -> np.ndarray:
    """Mesh output (468, 3) in crop pixels -> (468, 3) image pixels (continuous; z scaled like x)."""
    cx, cy, w, h, angle = (float(v) for v in roi)
    local = (raw[:, :2] / size - 0.5) * np.array([w, h])
    xy = local @ rotation_2d(angle).T + np.array([cx, cy])
    z = raw[:, 2:3] / size * w
    return np.hstack([xy, z])


def as_bgr_uint8(image) -> np.ndarray | None:
    """Coerce an image to (H, W, 3) uint8 BGR; None when it holds no pixels or is not an image.

    Accepts grey (H, W) or (H, W, 1), BGRA, float images (in [0, 1] when their maximum is at
    most 1, else [0, 255]), and other integer types (uint16 is scaled to 8 bits).
    """
    if not isinstance(image, np.ndarray):
        try:
            image = np.asarray(image)
        except Exception:  # noqa: BLE001 - anything not array-like is "not an image"
            return None
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim not in (2, 3) or image.size == 0 or (image.ndim == 3 and image.shape[2] not in (3, 4)):
        return None
    if image.dtype != np.uint8:
        if image.dtype == np.bool_:
            image = image.astype(np.uint8) * 255
        elif np.issubdtype(image.dtype, np.floating):
            img = np.nan_to_num(image.astype(np.float32), nan=0.0, posinf=255.0, neginf=0.0)
            if img.max(initial=0.0) <= 1.0:
                img = img * 255.0
            image = np.clip(img + 0.5, 0, 255).astype(np.uint8)
        elif image.dtype == np.uint16:
            image = (image >> 8).astype(np.uint8)
        elif np.issubdtype(image.dtype, np.integer):
            image = np.clip(image, 0, 255).astype(np.uint8)
        else:
            return None
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.shape[2] == 4:
        return np.ascontiguousarray(image[:, :, :3])
    return np.ascontiguousarray(image)


def _index_coords(face_points: np.ndarray, roi: np.ndarray, score: float, track_id: int = 0) -> Face:
    """Continuous coordinates -> pixel-index coordinates, as a :class:`Face`."""
    points = face_points.astype(np.float32)
    points[:, :2] -= 0.5
    out_roi = roi.astype(np.float32)
    out_roi[:2] -= 0.5
    return Face(points=points, score=float(score), roi=out_roi, track_id=int(track_id))


@dataclass
class _Track:
    """A tracked face, continuous coordinates: the crop its points came from, the points
    (468, 3), the presence score, and the ROI for the next frame."""

    crop_roi: np.ndarray
    points: np.ndarray
    score: float
    next_roi: np.ndarray
    track_id: int = -1


class LandmarkDetector:
    """Face detector + 468-point face mesh with ROI tracking.

    models_dir: the directory `facesculpt setup` filled (default :func:`model_home`); a missing
    file raises :class:`MissingModelsError` naming `facesculpt setup`. threads: onnxruntime
    intra-op threads. max_faces: how many faces to return (the largest first). min_face: the
    smallest face the detector looks for (detector box side, as a fraction of the image's short
    side; smaller faces need more tiles, see :func:`detection_tiles`); 0 = whole image only.
    min_detection_score, nms_iou: detector thresholds. min_tracking_score: face presence below
    which a face counts as lost. redetect_interval: frames between detector runs while fewer
    than ``max_faces`` faces are tracked. backend: "onnxruntime" (the converted networks) or
    "litert" (the original .tflite networks on ai-edge-litert, a reference for tests and
    benchmarks).

    ``detect(image)`` always runs the detector; ``track(image)`` reuses the last crops and runs
    the detector only when needed. Both return a list of :class:`Face` (empty when none) and
    never raise on bad images.
    """

    def __init__(self, models_dir: str | Path | None = None, threads: int = 1, max_faces: int = 1,
                 min_detection_score: float = 0.5, min_tracking_score: float = 0.5,
                 min_face: float = 0.15, nms_iou: float = 0.3, redetect_interval: int = 15,
                 backend: str = "onnxruntime"):
        home = Path(models_dir) if models_dir is not None else model_home()
        ext = {"onnxruntime": ".onnx", "litert": ".tflite"}.get(backend)
        if ext is None:
            raise ValueError(f"unknown backend {backend!r} (onnxruntime or litert)")
        paths = [home / name.replace(".onnx", ext) for name in _DETECTOR_FILES]
        for path in paths:
            if not path.is_file():
                raise MissingModelsError(
                    f"{path} is missing: run `facesculpt setup` to fetch and convert the face networks "
                    f"(or point FACESCULPT_HOME / models_dir at the directory where it put them)")
        if backend == "onnxruntime":
            self.detector_net, self.mesh_net = (OnnxNetwork(p, threads) for p in paths)
        else:
            self.detector_net, self.mesh_net = (LiteRtNetwork(p, threads) for p in paths)
        self.max_faces = max(int(max_faces), 1)
        self.min_detection_score = float(min_detection_score)
        self.min_tracking_score = float(min_tracking_score)
        self.min_face = max(float(min_face), 0.0)
        self.nms_iou = float(nms_iou)
        self.redetect_interval = max(int(redetect_interval), 1)
        self.anchors = ssd_anchors(DETECTOR_SIZE, _ANCHOR_STRIDES)
        self._tracks: list[_Track] = []
        self._next_track_id = 0
        self._frames_since_detect = 0
        self.last_ran_detector = False

    # ---- public API ----------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the tracked faces: the next :meth:`track` runs the detector, and track ids
        start again from 0 (the same video then gives its faces the same ids)."""
        self._tracks = []
        self._next_track_id = 0

    def detect(self, image) -> list[Face]:
        """Run the detector on the whole image (and tiles), then the mesh on each face found."""
        bgr = self._prepare(image)
        if bgr is None:
            self._tracks = []
            return []
        self._next_track_id = 0  # a still image: its faces are 0, 1, ... from the left
        self._tracks = self._detect_tracks(bgr, [])
        self._frames_since_detect = 0
        self.last_ran_detector = True
        return self._faces()

    def track(self, image) -> list[Face]:
        """Landmarks from the last crops; the detector reruns when a face is lost or fewer than
        ``max_faces`` are tracked (then at most every ``redetect_interval`` frames)."""
        bgr = self._prepare(image)
        if bgr is None:
            self._tracks = []
            return []
        self.last_ran_detector = False
        tracks: list[_Track] = []
        for old in self._tracks:
            track = self._refine(bgr, old.next_roi)
            # Two tracks that drifted onto one face become one.
            if track is not None and not any(_roi_overlap(track.next_roi, t.points) for t in tracks):
                track.track_id = old.track_id
                tracks.append(track)
        lost = len(tracks) < len(self._tracks)
        self._frames_since_detect += 1
        if not tracks or lost or (len(tracks) < self.max_faces
                                  and self._frames_since_detect >= self.redetect_interval):
            tracks = self._detect_tracks(bgr, tracks)
            self._frames_since_detect = 0
            self.last_ran_detector = True
        self._tracks = tracks
        return self._faces()

    # ---- steps ---------------------------------------------------------------------------
    def _prepare(self, image) -> np.ndarray | None:
        return as_bgr_uint8(image)

    def run_detector(self, bgr: np.ndarray) -> list[Detection]:
        """All detections in a BGR uint8 image (continuous pixels), merged over tiles."""
        h, w = bgr.shape[:2]
        min_face = self.min_face * min(w, h)
        boxes, keypoints, scores = [], [], []
        for i, (x0, y0, side) in enumerate(detection_tiles(w, h, min_face)):
            patch = crop_image(bgr, np.array([x0 + side / 2, y0 + side / 2, side, side, 0.0]),
                               DETECTOR_SIZE, cv2.BORDER_CONSTANT)
            x = (patch[:, :, ::-1].astype(np.float32) * (1.0 / 127.5) - 1.0)[None]  # RGB in [-1, 1]
            raw_boxes, raw_scores = self.detector_net.run(x)
            b, k, s = decode_ssd(raw_boxes[0], raw_scores[0, :, 0], self.anchors, DETECTOR_SIZE, NUM_KEYPOINTS,
                                 self.min_detection_score)
            if i > 0 and len(s):
                keep = _owned_by_tile(b, x0 / side, y0 / side, w / side, h / side)
                b, k, s = b[keep], k[keep], s[keep]
            if len(s):
                boxes.append(b * side + np.array([x0, y0, x0, y0], np.float32))
                keypoints.append(k * side + np.array([x0, y0], np.float32))
                scores.append(s)
        if not scores:
            return []
        return weighted_nms(np.concatenate(boxes), np.concatenate(keypoints), np.concatenate(scores),
                            self.nms_iou)

    def _refine(self, bgr: np.ndarray, roi: np.ndarray) -> _Track | None:
        """Mesh on one ROI; None when the face-presence score is below ``min_tracking_score``."""
        if not (np.all(np.isfinite(roi)) and roi[2] >= 4.0):
            return None
        crop = crop_image(bgr, roi, MESH_SIZE)
        x = (crop[:, :, ::-1].astype(np.float32) * (1.0 / 255.0))[None]  # RGB in [0, 1]
        raw_points, raw_score = self.mesh_net.run(x)
        score = 1.0 / (1.0 + math.exp(-float(np.clip(raw_score.reshape(-1)[0], -100, 100))))
        if score < self.min_tracking_score:
            return None
        points = project_points(raw_points.reshape(NUM_POINTS, 3).astype(np.float64), roi)
        return _Track(crop_roi=roi, points=points, score=score, next_roi=roi_from_points(points[:, :2]))

    def _detect_tracks(self, bgr: np.ndarray, tracks: list[_Track]) -> list[_Track]:
        """Add faces from the detector to the tracked ones, up to ``max_faces`` (largest first).

        Detections are taken best score first (the order of :func:`weighted_nms`); one that
        covers an already accepted face is a duplicate and is skipped.
        """
        found: list[_Track] = []
        for det in self.run_detector(bgr):
            roi = roi_from_detection(det)
            if any(_roi_overlap(roi, t.points) for t in tracks + found):
                continue
            track = self._refine(bgr, roi)
            if track is not None:
                # A second pass from the mesh's own ROI: detector boxes are coarse, and on still
                # images there is no next frame to correct the crop.
                track = self._refine(bgr, track.next_roi) or track
            if track is not None and not any(_roi_overlap(track.next_roi, t.points) for t in tracks + found):
                found.append(track)
        found.sort(key=lambda t: -t.next_roi[2])
        found = sorted(found[: max(self.max_faces - len(tracks), 0)], key=lambda t: t.next_roi[0])
        for track in found:  # new faces are numbered left to right
            track.track_id = self._next_track_id
            self._next_track_id += 1
        return tracks + found

    def _faces(self) -> list[Face]:
        tracks = sorted(self._tracks, key=lambda t: -t.next_roi[2])[: self.max_faces]
        return [_index_coords(t.points, t.crop_roi, t.score, t.track_id) for t in tracks]


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


def _roi_overlap(roi: np.ndarray, points: np.ndarray) -> bool:
    """True when a tracked face's nose tip (mesh point 1) lies inside the central half of ``roi``."""
    nose = points[1, :2]
    local = (nose - roi[:2]) @ rotation_2d(float(roi[4]))
    return bool(np.all(np.abs(local) < roi[2:4] / 4.0))
