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
        import onnxruntime as ort

        path = (Path(models_dir) if models_dir is not None else model_home()) / NETWORK_FILE
        if not path.is_file():
            raise MissingNetworkError(f"{path} is missing: run `facesculpt setup` to convert the person "
                                      f"segmentation the background plate needs")
        options = ort.SessionOptions()
        options.intra_op_num_threads = max(int(threads), 0)
        options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        self.input_name = self.session.get_inputs()[0].name

    def probability(self, frame_bgr: np.ndarray, box: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """(h, w) float32 in [0, 1]: how likely each pixel of ``box`` (x0, y0, x1, y1, inside the
        frame; None: the whole frame) of ``frame_bgr`` ((H, W, 3) uint8 BGR) is a person's. The
        network sees the whole frame; its 256x256 output is resized bilinearly to the box only."""
        h, w = frame_bgr.shape[:2]
        x0, y0, x1, y1 = box if box is not None else (0, 0, w, h)
        small = cv2.resize(frame_bgr, (INPUT_SIZE, INPUT_SIZE), interpolation=cv2.INTER_AREA)
        x = cv2.cvtColor(small, cv2.COLOR_BGR2RGB).astype(np.float32)[None] * np.float32(1.0 / 255.0)
        out = self.session.run(None, {self.input_name: x})[0].reshape(INPUT_SIZE, INPUT_SIZE)
        # the box's pixels in the output's coordinates (pixel centres: x_out = (x + 0.5) * 256 / w - 0.5)
        sx, sy = INPUT_SIZE / w, INPUT_SIZE / h
        A = np.array([[sx, 0.0, (x0 + 0.5) * sx - 0.5], [0.0, sy, (y0 + 0.5) * sy - 0.5]])
        return cv2.warpAffine(out, A, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REPLICATE)

    def mask(self, frame_bgr: np.ndarray) -> np.ndarray:
        """(H, W) uint8 0/1: the pixels of ``frame_bgr`` that are a person's (probability above
        PERSON_THRESHOLD)."""
        return (self.probability(frame_bgr) > PERSON_THRESHOLD).view(np.uint8)

    __call__ = mask
