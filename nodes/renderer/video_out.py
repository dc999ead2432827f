"""Writing the rendered frames to a video file (OpenCV's VideoWriter)."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

# Codecs OpenCV's bundled FFmpeg writes without extra libraries.
FOURCC_BY_SUFFIX = {".mp4": "mp4v", ".m4v": "mp4v", ".mov": "mp4v", ".avi": "MJPG", ".mkv": "MJPG"}


class VideoOutput:
    """Appends (H, W, 3) uint8 BGR frames to ``path`` at ``fps`` frames per second.

    The file is opened at the first frame (its size fixes the video's); the codec follows
    the suffix (FOURCC_BY_SUFFIX). Raises ValueError for an unknown suffix or a frame of
    another size, RuntimeError when the file cannot be opened for writing.

    OpenCV's writer fails silently on a full disk and would leave a file without its index
    (unplayable). So before each frame the free space is checked: below ``reserve_bytes``
    (default: one raw frame, at least 1 MiB) the file is finalised -- what was written stays
    playable -- and OSError(ENOSPC) is raised once; later frames are dropped (``dropped``).
    """

    def __init__(self, path: str | Path, fps: float = 30.0, reserve_bytes: int | None = None):
        self.path = Path(path).expanduser()
        suffix = self.path.suffix.lower()
        if suffix not in FOURCC_BY_SUFFIX:
            raise ValueError(f"video output {self.path}: unknown suffix {suffix!r} "
                             f"(known: {', '.join(sorted(FOURCC_BY_SUFFIX))})")
        if not fps > 0:
            raise ValueError(f"video output fps must be > 0, got {fps}")
        self.fps = float(fps)
        self.fourcc = FOURCC_BY_SUFFIX[suffix]
        self.size: tuple[int, int] | None = None
        self.frames = 0
        self.dropped = 0
        self.failed = ""
        self.reserve_bytes = reserve_bytes
        self._writer: cv2.VideoWriter | None = None

    def write(self, frame_bgr: np.ndarray) -> None:
        if not (isinstance(frame_bgr, np.ndarray) and frame_bgr.dtype == np.uint8 and frame_bgr.ndim == 3
                and frame_bgr.shape[2] == 3):
            raise ValueError("video output takes (H, W, 3) uint8 BGR frames")
        h, w = frame_bgr.shape[:2]
        if self.failed:
            self.dropped += 1
            return
        if self._writer is None:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise RuntimeError(f"cannot open {self.path} for writing: {exc.strerror}") from None
            self._writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*self.fourcc), self.fps, (w, h))
            if not self._writer.isOpened():
                self._writer = None
                raise RuntimeError(f"cannot open {self.path} for writing ({self.fourcc}, {w}x{h})")
            self.size = (w, h)
        elif (w, h) != self.size:
            raise ValueError(f"video output {self.path} is {self.size[0]}x{self.size[1]}; got a {w}x{h} frame")
        reserve = self.reserve_bytes if self.reserve_bytes is not None else max(1 << 20, frame_bgr.nbytes)
        free = _free_bytes(self.path.parent)
        if free is not None and free < reserve:
            self.close()  # finalise while there is still room for the index
            self.failed = (f"video output {self.path}: disk full ({free} bytes free) after {self.frames} frames; "
                           f"those frames are saved, later ones are dropped")
            self.dropped += 1
            raise OSError(28, self.failed)
        self._writer.write(frame_bgr)
        self.frames += 1

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None

    def __enter__(self) -> VideoOutput:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _free_bytes(directory: Path) -> int | None:
    """Bytes available to us on the filesystem of ``directory`` (None when unknown)."""
    try:
        st = os.statvfs(directory)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize
