"""The landmarks node: camera/image -> face/landmarks (468 face-mesh points per face).

A thin shell around :class:`LandmarkDetector`: each frame is tracked from the last crops
(the detector reruns only when a face is lost), the source stamp is kept, and a frame without
a face gives an empty message (F = 0). Run it with ``facesculpt run landmarks threads=2``.
"""

from __future__ import annotations

import numpy as np

from facesculpt.msgs import FaceLandmarks, Image
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import Param

from .detector import NUM_POINTS, LandmarkDetector


class LandmarksNode(Node):
    """Publishes face/landmarks for every camera/image (latest-only)."""

    NAME = "landmarks"
    PARAMS = {
        "models_dir": Param("", "directory filled by `facesculpt setup` (\"\": FACESCULPT_HOME / cache)"),
        "threads": Param(1, "onnxruntime intra-op threads per network (0: onnxruntime's default)", range=(0, 64)),
        "max_faces": Param(1, "faces tracked, largest first", range=(1, 16)),
        "min_detection_score": Param(0.5, "detector score threshold", range=(0.0, 1.0)),
        "min_tracking_score": Param(0.5, "face-presence score below which the detector reruns", range=(0.0, 1.0)),
        "min_face": Param(0.15, "smallest face to detect, fraction of the short image side (0: whole image only)",
                          range=(0.0, 1.0)),
        "redetect_interval": Param(15, "frames between detector runs while fewer than max_faces are tracked",
                                   range=(1, 1000)),
        "track": Param(True, "track faces from frame to frame (false: run the detector on every frame)"),
    }

    def setup(self):
        p = self.params
        self.detector = LandmarkDetector(
            models_dir=p.models_dir or None, threads=p.threads, max_faces=p.max_faces,
            min_detection_score=p.min_detection_score, min_tracking_score=p.min_tracking_score,
            min_face=p.min_face, redetect_interval=p.redetect_interval)
        self.pub = self.advertise("face/landmarks", FaceLandmarks)
        self.subscribe("camera/image", Image, self.on_image)
        self.log.info("face networks loaded (threads=%d, max_faces=%d)", p.threads, p.max_faces)

    def on_image(self, msg: Image):
        image = msg.image
        if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[0] == 0 or image.shape[1] == 0:
            self.count("bad_image")
            faces, size = [], [0, 0]
        else:
            size = [int(image.shape[1]), int(image.shape[0])]
            with self.stage("landmarks"):
                faces = self.detector.track(image) if self.params.track else self.detector.detect(image)
            if self.detector.last_ran_detector:
                self.count("detector_runs")
        if not faces:
            self.count("no_face")
        self.pub.publish(FaceLandmarks(
            stamp=msg.stamp, seq=msg.seq, frame_id=msg.frame_id,
            points=np.stack([f.points for f in faces]) if faces else np.zeros((0, NUM_POINTS, 3), np.float32),
            scores=np.array([f.score for f in faces], np.float32),
            rois=np.stack([f.roi for f in faces]).astype(np.float32) if faces else np.zeros((0, 5), np.float32),
            track_ids=np.array([f.track_id for f in faces], np.int32), image_size=size, K=msg.K))


if __name__ == "__main__":
    LandmarksNode.main()
