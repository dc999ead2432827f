"""Two of the shared videos side by side: two people in one 1024x512 frame, written losslessly
(FFV1, with the realism benchmark's writer) so that a test knows the input frames exactly."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.realism.sequences import read_video, write_lossless


def write_two_people(data_dir: Path, path: Path, frames: int) -> list[np.ndarray]:
    """d0 (left) and d3 (right), ``frames`` frames at 25 fps into ``path`` (.mkv); returns the frames."""
    left = read_video(data_dir / "video" / "d0.mp4", frames)
    right = read_video(data_dir / "video" / "d3.mp4", frames)
    out = [np.hstack([a, b]) for a, b in zip(left, right)]
    write_lossless(out, path, fps=25)
    return out
