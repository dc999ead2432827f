"""Two of the shared videos side by side: two people in one 1024x512 frame, written losslessly
(FFV1) so that a test knows the input frames exactly."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def frames_of(path: Path, n: int) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    out = []
    while len(out) < n:
        ok, frame = cap.read()
        if not ok:
            break
        out.append(frame)
    cap.release()
    return out


def write_two_people(data_dir: Path, path: Path, frames: int) -> list[np.ndarray]:
    """d0 (left) and d3 (right), ``frames`` frames at 25 fps into ``path`` (.mkv); returns the frames."""
    import av

    left = frames_of(data_dir / "video" / "d0.mp4", frames)
    right = frames_of(data_dir / "video" / "d3.mp4", frames)
    out = [np.hstack([a, b]) for a, b in zip(left, right)]
    with av.open(str(path), "w") as box:
        stream = box.add_stream("ffv1", rate=25)
        stream.width, stream.height, stream.pix_fmt = 1024, 512, "bgr0"
        for f in out:
            for packet in stream.encode(av.VideoFrame.from_ndarray(f, format="bgr24")):
                box.mux(packet)
        for packet in stream.encode():
            box.mux(packet)
    return out
