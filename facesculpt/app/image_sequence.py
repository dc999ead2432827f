"""An output written as numbered lossless images (``out/%05d.png``): `process`'s frames, and the
edited depth's 16-bit images."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

LOSSLESS_SUFFIXES = (".png", ".bmp", ".tif", ".tiff")


class ImageSequenceOutput:
    """Writes frames as numbered lossless images: ``pattern % index`` with index from 0."""

    def __init__(self, pattern: str):
        try:
            first = pattern % 0
        except (TypeError, ValueError):
            raise ValueError(f"output pattern {pattern!r} must hold one integer field such as %05d") from None
        if first == pattern % 1:
            raise ValueError(f"output pattern {pattern!r} gives every frame the same name")
        if Path(first).suffix.lower() not in LOSSLESS_SUFFIXES:
            raise ValueError(f"output pattern {pattern!r}: image sequences are written losslessly, as "
                             f"{', '.join(LOSSLESS_SUFFIXES)}")
        self.pattern = pattern
        self.path = pattern
        self.frames = 0

    def write(self, frame_bgr: np.ndarray) -> None:
        path = Path(self.pattern % self.frames)
        path.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(path), frame_bgr):
            raise RuntimeError(f"cannot write {path}")
        self.frames += 1

    def close(self) -> None:
        pass
