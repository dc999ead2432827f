"""The track-and-redetect loop that the face-mesh and hands detectors share (mediapipe's
detection -> landmarks -> next crop graph, written out once).

An object (a face, a hand) is found by an SSD detector, whose detection gives a first crop (ROI);
a landmark network on that crop gives the object's points and a presence score; the points give
the next frame's crop. The detector runs again only when an object is lost (presence below
``min_tracking_score``), when none is tracked, or, while fewer than ``max_tracked`` are tracked,
every ``redetect_interval`` frames. Two crops that end on one object become one.

:class:`RoiTracker` is that loop; a detector derives from it and supplies the networks
(:meth:`~RoiTracker.run_detector`, :meth:`~RoiTracker.run_landmarks`), the crop rules
(:meth:`~RoiTracker.detection_roi`, :meth:`~RoiTracker.landmarks_roi`), the point that tells
whether a crop is on a tracked object (:meth:`~RoiTracker.anchor`) and the results
(:meth:`~RoiTracker.results`). Coordinates are continuous image pixels (pixel i spans [i, i + 1]).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesculpt.geometry.bgr_image import as_bgr_uint8
from facesculpt.geometry.crops import crop_to_image, in_central_half, network_input
from facesculpt.geometry.detections import Detection
from facesculpt.geometry.detector_options import DetectorOptions, with_values


@dataclass
class Track:
    """A tracked object, continuous pixels: ``crop_roi`` (5,) the crop its points came from,
    ``points`` (N, 3) image pixels (z scaled like x), ``score`` its presence in [0, 1],
    ``next_roi`` (5,) the crop for the next frame, ``label`` what the network says beside the
    points (the hands: the probability of the person's right hand; else 0), ``track_id``."""

    crop_roi: np.ndarray
    points: np.ndarray
    score: float
    next_roi: np.ndarray
    label: float = 0.0
    track_id: int = -1


def sigmoid(logit: float) -> float:
    """A score from a logit, clipped to +-100 first."""
    return 1.0 / (1.0 + math.exp(-float(np.clip(logit, -100, 100))))


class RoiTracker:
    """The loop over the last crops with the detector run when needed (see the module).

    Constructed with ``models_dir`` and ``options`` (None: the class's ``defaults``), and single
    options as keyword arguments (field names, or the detector's ``aliases`` for them).
    A subclass sets ``crop_size`` (the landmark network's input side, pixels) and
    ``keep_largest`` (True: every detection is refined and the largest objects are kept, as the
    face detector does; False: detections are refined best first until ``max_tracked`` are
    tracked), and implements the hooks below. ``detect(image)`` always runs the detector;
    ``track(image)`` reuses the last crops. Both return :meth:`results` (empty when nothing is
    found) and never raise on bad images.
    """

    crop_size = 0
    keep_largest = False
    #: The detector's own options, and its own names for some of their fields.
    defaults = DetectorOptions()
    aliases: dict[str, str] = {}

    def __init__(self, models_dir: str | Path | None = None, options: DetectorOptions | None = None, **values):
        options = with_values(options or self.defaults, self.aliases, {"models_dir": models_dir, **values})
        self.options = options
        self.max_tracked = options.max_tracked
        self.min_detection_score = float(options.min_detection_score)
        self.min_tracking_score = float(options.min_tracking_score)
        self.nms_iou = float(options.nms_iou)
        self.redetect_interval = max(int(options.redetect_interval), 1)
        self._tracks: list[Track] = []
        self._next_track_id = 0
        self._frames_since_detect = 0
        self.last_ran_detector = False
        self.load(options)

    @property
    def max_tracked(self) -> int:
        """The most objects tracked at once (at least 1; may be changed between frames)."""
        return self._max_tracked

    @max_tracked.setter
    def max_tracked(self, value: int) -> None:
        self._max_tracked = max(int(value), 1)

    # ---- the hooks a detector implements ---------------------------------------------------
    def load(self, options: DetectorOptions) -> None:
        """Load the networks (and keep what else the detector takes from ``options``)."""
        raise NotImplementedError

    def prepare(self, image) -> np.ndarray | None:
        """The image as (H, W, 3) uint8 BGR, or None when it cannot be one (by default
        :func:`~facesculpt.geometry.bgr_image.as_bgr_uint8`)."""
        return as_bgr_uint8(image)

    def run_detector(self, bgr: np.ndarray) -> list[Detection]:
        """Every detection in a BGR uint8 image (continuous pixels), best first."""
        raise NotImplementedError

    def detection_roi(self, detection: Detection) -> np.ndarray:
        """The first crop (5,) of a detection."""
        raise NotImplementedError

    def run_landmarks(self, x: np.ndarray) -> tuple[np.ndarray, float, float]:
        """The landmark network on one input (1, S, S, 3): points (N, 3) float64 in crop pixels,
        presence score in [0, 1], label (see :class:`Track`)."""
        raise NotImplementedError

    def landmarks_roi(self, points_xy: np.ndarray) -> np.ndarray:
        """The next frame's crop (5,) from an object's points (N, 2)."""
        raise NotImplementedError

    def anchor(self, points: np.ndarray) -> np.ndarray:
        """The point (2,) of an object that a crop on it holds in its central half."""
        raise NotImplementedError

    def same(self, a: Track, b: Track) -> bool:
        """Two tracks on one object (by default: ``b``'s anchor in the central half of ``a``'s next crop)."""
        return in_central_half(self.anchor(b.points), a.next_roi)

    def results(self) -> list:
        """What :meth:`detect` and :meth:`track` return, from ``self._tracks``."""
        raise NotImplementedError

    # ---- the loop ----------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the tracked objects: the next :meth:`track` runs the detector, and track ids
        start again from 0 (the same video then gives its objects the same ids)."""
        self._tracks = []
        self._next_track_id = 0

    def detect(self, image) -> list:
        """Run the detector, then the landmarks on each object found (a still image: ids from 0)."""
        bgr = self.prepare(image)
        if bgr is None:
            self._tracks = []
            return []
        self._next_track_id = 0
        self._tracks = self._detect_tracks(bgr, [])
        self._frames_since_detect = 0
        self.last_ran_detector = True
        return self.results()

    def track(self, image) -> list:
        """Landmarks from the last crops; the detector reruns when an object is lost, when none is
        tracked, or, while fewer than ``max_tracked`` are, every ``redetect_interval`` frames."""
        bgr = self.prepare(image)
        if bgr is None:
            self._tracks = []
            return []
        self.last_ran_detector = False
        tracks: list[Track] = []
        for old in self._tracks:
            track = self.refine(bgr, old.next_roi)
            if track is not None and not any(self.same(track, t) for t in tracks):
                track.track_id = old.track_id
                tracks.append(track)
        lost = len(tracks) < len(self._tracks)
        self._frames_since_detect += 1
        if not tracks or lost or (len(tracks) < self.max_tracked
                                  and self._frames_since_detect >= self.redetect_interval):
            tracks = self._detect_tracks(bgr, tracks)
            self._frames_since_detect = 0
            self.last_ran_detector = True
        self._tracks = tracks
        return self.results()

    def refine(self, bgr: np.ndarray, roi: np.ndarray) -> Track | None:
        """Landmarks on one crop; None when the presence score is below ``min_tracking_score``."""
        if not (np.all(np.isfinite(roi)) and roi[2] >= 4.0):
            return None
        raw, score, label = self.run_landmarks(network_input(bgr, roi, self.crop_size))
        if score < self.min_tracking_score:
            return None
        points = crop_to_image(raw, roi, self.crop_size)
        return Track(crop_roi=roi, points=points, score=score, next_roi=self.landmarks_roi(points[:, :2]),
                     label=label)

    def _detect_tracks(self, bgr: np.ndarray, tracks: list[Track]) -> list[Track]:
        """Add objects from the detector to the tracked ones, up to ``max_tracked``, numbered left
        to right. A detection whose crop holds a tracked object's anchor is skipped."""
        found: list[Track] = []
        for det in self.run_detector(bgr):
            if not self.keep_largest and len(tracks) + len(found) >= self.max_tracked:
                break
            roi = self.detection_roi(det)
            if any(in_central_half(self.anchor(t.points), roi) for t in tracks + found):
                continue
            track = self.refine(bgr, roi)
            if track is not None:
                # A second pass from the points' own crop: detector boxes are coarse, and a still
                # image has no next frame to correct the crop.
                track = self.refine(bgr, track.next_roi) or track
            if track is not None and not any(self.same(track, t) for t in tracks + found):
                found.append(track)
        if self.keep_largest:
            found.sort(key=lambda t: -t.next_roi[2])
            found = found[: max(self.max_tracked - len(tracks), 0)]
        found.sort(key=lambda t: t.next_roi[0])
        for track in found:
            track.track_id = self._next_track_id
            self._next_track_id += 1
        return tracks + found
