"""The landmarks node: camera/image -> face/landmarks (468 face-mesh points per face).

A thin shell around :class:`LandmarkDetector`: each frame is tracked from the last crops
(the detector reruns only when a face is lost), the source stamp is kept, and a frame without
a face gives an empty message (F = 0). Run it with ``facesculpt run landmarks threads=2``.

A frame larger than ``max_pixels`` is tracked on a copy halved to fit (:mod:`.working_resolution`);
with ``image_topic: camera/analysis`` the camera sends such a copy itself (its
``analysis_pixels``). Either way the points, crops and K are the full frame's.
"""

from __future__ import annotations

import numpy as np

from facesculpt.geometry.halving import frame_intrinsics, halve, halvings
from facesculpt.msgs import FaceLandmarks, Image
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import Param, option_params

from .detector import FACE_ALIASES, FACE_OPTIONS, NUM_POINTS, LandmarkDetector
from .working_resolution import ANALYSIS_PIXELS, to_full_resolution

# The detector's options the node declares as parameters (their defaults, ranges and help: FACE_OPTIONS).
DETECTOR_PARAMS = ("models_dir", "threads", "max_faces", "min_detection_score", "min_tracking_score", "min_face",
                   "redetect_interval")


class LandmarksNode(Node):
    """Publishes face/landmarks for every camera/image (latest-only)."""

    NAME = "landmarks"
    TOPICS = ("face/landmarks",)
    PARAMS = {
        **option_params(FACE_OPTIONS, DETECTOR_PARAMS, FACE_ALIASES),
        "image_topic": Param("camera/image", "the frames to track: camera/image, or camera/analysis (a halved "
                                             "copy the camera sends with analysis_pixels set)", topic=True),
        "max_pixels": Param(ANALYSIS_PIXELS, "track a larger frame on a copy halved until it holds at most this "
                                             "many pixels (0: the frame as it comes)", range=(0, None)),
        "track": Param(True, "track faces from frame to frame (false: run the detector on every frame)"),
    }

    def setup(self):
        p = self.params
        self.detector = LandmarkDetector(**{name: getattr(p, name) for name in DETECTOR_PARAMS})
        self.pub = self.advertise("face/landmarks", FaceLandmarks)
        self.scale = None  # (this node's halvings, the camera's): a change restarts tracking
        self.subscribe(p.image_topic, Image, self.on_image)
        self.log.info("face networks loaded (threads=%d, max_faces=%d)", p.threads, p.max_faces)

    def on_image(self, msg: Image):
        image = msg.image
        K = msg.K
        if not _usable(msg):
            self.count("bad_image")
            faces, size = [], [0, 0]
        else:
            h, w = image.shape[:2]
            halved = int(msg.halvings)
            size = [int(v) for v in msg.frame_size] if halved else [w, h]
            times = halvings(w, h, self.params.max_pixels)
            if self.scale != (times, halved):
                self.detector.reset()  # the tracker's crops are in the pixels of the copy it tracked
                self.scale = (times, halved)
            with self.stage("landmarks"):
                work = halve(image, times)
                faces = to_full_resolution(self.detector.track(work) if self.params.track
                                           else self.detector.detect(work), times + halved)
            K = frame_intrinsics(K, halved)
            if self.detector.last_ran_detector:
                self.count("detector_runs")
        if not faces:
            self.count("no_face")
        self.pub.publish(FaceLandmarks(
            stamp=msg.stamp, seq=msg.seq, frame_id=msg.frame_id,
            points=np.stack([f.points for f in faces]) if faces else np.zeros((0, NUM_POINTS, 3), np.float32),
            scores=np.array([f.score for f in faces], np.float32),
            rois=np.stack([f.roi for f in faces]).astype(np.float32) if faces else np.zeros((0, 5), np.float32),
            track_ids=np.array([f.track_id for f in faces], np.int32), image_size=size, K=K))


def _usable(msg: Image) -> bool:
    """A non-empty image, and for a halved copy a sane count and a frame size it can come from."""
    image = msg.image
    if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[0] == 0 or image.shape[1] == 0:
        return False
    halved = msg.halvings
    if halved == 0:
        return True
    if not 0 < halved <= 8 or len(msg.frame_size) != 2:
        return False
    w, h = msg.frame_size
    return isinstance(w, int) and isinstance(h, int) and w >> halved == image.shape[1] and h >> halved == image.shape[0]


if __name__ == "__main__":
    LandmarksNode.main()
