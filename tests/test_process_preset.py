"""The encoder's speed preset: ``auto`` keeps x264's own default up to 1920x1080 (the same bytes as
before the option existed) and takes ultrafast above; a named one is used as given."""

from __future__ import annotations

import numpy as np
import pytest

from facesculpt.nodes.renderer.video_out import VideoOutput


def _write(path, size, preset):
    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, (size[1] // 8, size[0] // 8, 3), np.uint8)
    with VideoOutput(path, 25.0, codec="libx264", preset=preset) as out:
        for i in range(3):
            out.write(np.ascontiguousarray(np.roll(np.kron(base, np.ones((8, 8, 1), np.uint8)), 4 * i, axis=1)))
    return path.read_bytes()


def test_auto_is_the_default_up_to_1080p_and_ultrafast_above(tmp_path):
    small_auto = _write(tmp_path / "a.mp4", (640, 360), "auto")
    assert small_auto == _write(tmp_path / "b.mp4", (640, 360), None)
    assert b"cabac=1" in small_auto  # x264's settings, in its SEI: medium codes with CABAC
    large_auto = _write(tmp_path / "c.mp4", (2048, 1152), "auto")
    assert b"cabac=0" in large_auto and large_auto == _write(tmp_path / "d.mp4", (2048, 1152), "ultrafast")
    assert b"cabac=0" not in _write(tmp_path / "e.mp4", (2048, 1152), "veryfast")


def test_an_unknown_preset_is_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown encoder preset 'quick'"):
        VideoOutput(tmp_path / "x.mp4", 25.0, preset="quick")


def test_large_frames_keep_their_colours(tmp_path):
    """Above 1920x1080 the 4:2:0 conversion is OpenCV's: red stays red, blue blue (planes in order),
    and the decoded frame is close to the one written."""
    import av

    frame = np.zeros((1152, 2048, 3), np.uint8)
    frame[:, :512] = (0, 0, 255)        # red (BGR)
    frame[:, 512:1024] = (255, 0, 0)    # blue
    frame[:, 1024:1536] = (40, 180, 90)  # a green
    frame[:, 1536:] = np.linspace(0, 255, 512, dtype=np.uint8)[None, :, None]  # grey ramp
    with VideoOutput(tmp_path / "big.mp4", 25.0, preset="auto") as out:
        out.write(frame)
    with av.open(str(tmp_path / "big.mp4")) as c:
        got = next(c.decode(video=0)).to_ndarray(format="bgr24")
    for x0 in (0, 512, 1024):
        centre = got[400:700, x0 + 100:x0 + 400].reshape(-1, 3).mean(axis=0)
        assert np.abs(centre - frame[500, x0 + 200]).max() < 6, (x0, centre)
    mse = np.mean((got.astype(np.float64) - frame) ** 2)
    assert 10 * np.log10(255 ** 2 / mse) > 30
