"""Where people are in a frame: mediapipe's selfie segmentation (general, 256x256), converted by
`facesculpt setup` into ``person_segmentation.onnx`` and run by onnxruntime.

The background plate (:mod:`.background_plate`) must learn only the background. The face's hull
alone leaves a person's hair, ears, neck and shoulders to it; the plate then shows them, stale,
where an edit uncovers the background after the person has moved. The compositor therefore keeps
the plate off every pixel this network gives to a person, and takes from the plate only what does
not show one (:class:`.compositor.Compositor`'s ``segmenter``; :mod:`.plate_learning`).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from facesculpt.networks import OnnxNetwork
from facesculpt.paths import model_home

NETWORK_FILE = "person_segmentation.onnx"
INPUT_SIZE = 256           # the network's square input, px (the frame is stretched to it, as mediapipe does)
PERSON_THRESHOLD = 0.5     # probability above which a pixel is a person's


class MissingNetworkError(FileNotFoundError):
    """The converted network is not in the model directory; the message says what to run."""


class PersonSegmenter:
    """PersonSegmenter(models_dir=None, threads=1): the network from ``models_dir`` (default
    :func:`facesculpt.paths.model_home`) on ``threads`` onnxruntime threads. Raises
    :class:`MissingNetworkError` when `facesculpt setup` has not converted it.

    Calling it on a frame gives the (H, W) uint8 0/1 mask of people (:meth:`mask`)."""

    def __init__(self, models_dir: str | Path | None = None, threads: int = 1):
        path = (Path(models_dir) if models_dir is not None else model_home()) / NETWORK_FILE
        if not path.is_file():
            raise MissingNetworkError(f"{path} is missing: run `facesculpt setup` to convert the person "
                                      f"segmentation the background plate needs")
        self.network = OnnxNetwork(path, threads)

    def probability(self, frame_bgr: np.ndarray) -> np.ndarray:
        """(H, W) float32 in [0, 1]: how likely each pixel of ``frame_bgr`` ((H, W, 3) uint8 BGR)
        is a person's: the network's 256x256 output resized bilinearly to the frame."""
        h, w = frame_bgr.shape[:2]
        small = cv2.resize(frame_bgr, (INPUT_SIZE, INPUT_SIZE), interpolation=cv2.INTER_AREA)
        x = cv2.cvtColor(small, cv2.COLOR_BGR2RGB).astype(np.float32)[None] * np.float32(1.0 / 255.0)
        out = self.network.run(x)[0].reshape(INPUT_SIZE, INPUT_SIZE)
        return cv2.resize(out, (w, h), interpolation=cv2.INTER_LINEAR)

    def mask(self, frame_bgr: np.ndarray) -> np.ndarray:
        """(H, W) uint8 0/1: the pixels of ``frame_bgr`` that are a person's (probability above
        PERSON_THRESHOLD)."""
        return (self.probability(frame_bgr) > PERSON_THRESHOLD).view(np.uint8)

    __call__ = mask
