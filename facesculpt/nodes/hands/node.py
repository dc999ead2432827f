"""The hands node: camera/image -> hands/landmarks (21 points per hand, up to ``max_hands``).

A thin shell around :class:`HandDetector`: each frame is tracked from the last crops (the palm
detector reruns when a hand is lost), the source stamp is kept, and a frame without a hand
gives an empty message (N = 0). Run it with ``facesculpt run hands``.
"""

from __future__ import annotations

import numpy as np

from facesculpt.msgs import HandLandmarks, Image
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import Param, option_params

from .detector import HAND_ALIASES, HAND_OPTIONS, NUM_HAND_POINTS, HandDetector

# The detector's options the node declares as parameters (their defaults, ranges and help: HAND_OPTIONS).
DETECTOR_PARAMS = ("models_dir", "threads", "max_hands", "min_detection_score", "min_tracking_score",
                   "redetect_interval", "mirrored")


class HandsNode(Node):
    """Publishes hands/landmarks for every camera/image (latest-only)."""

    NAME = "hands"
    TOPICS = ("hands/landmarks", "camera/image")
    PARAMS = {
        **option_params(HAND_OPTIONS, DETECTOR_PARAMS, HAND_ALIASES),
        "track": Param(True, "track hands from frame to frame (false: run the palm detector on every frame)"),
    }

    def setup(self):
        p = self.params
        self.detector = HandDetector(**{name: getattr(p, name) for name in DETECTOR_PARAMS})
        self.pub = self.advertise("hands/landmarks", HandLandmarks)
        self.subscribe("camera/image", Image, self.on_image)
        self.log.info("hand networks loaded (threads=%d, max_hands=%d)", p.threads, p.max_hands)

    def on_image(self, msg: Image):
        image = msg.image
        if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[0] == 0 or image.shape[1] == 0:
            self.count("bad_image")
            hands, size = [], [0, 0]
        else:
            size = [int(image.shape[1]), int(image.shape[0])]
            with self.stage("hands"):
                hands = self.detector.track(image) if self.params.track else self.detector.detect(image)
            if self.detector.last_ran_detector:
                self.count("detector_runs")
        if not hands:
            self.count("no_hand")
        self.pub.publish(hands_message(hands, size, msg))


def hands_message(hands, size, source: Image) -> HandLandmarks:
    """The :class:`HandLandmarks` of ``hands`` (a list of :class:`Hand`), stamped as ``source``."""
    n = len(hands)
    return HandLandmarks(
        stamp=source.stamp, seq=source.seq, frame_id=source.frame_id,
        points=np.stack([h.points for h in hands]) if n else np.zeros((0, NUM_HAND_POINTS, 3), np.float32),
        scores=np.array([h.score for h in hands], np.float32),
        right=np.array([h.right for h in hands], np.float32),
        rois=np.stack([h.roi for h in hands]).astype(np.float32) if n else np.zeros((0, 5), np.float32),
        track_ids=np.array([h.track_id for h in hands], np.int32), image_size=list(size), K=source.K)


if __name__ == "__main__":
    HandsNode.main()
