"""Resizing keeps the aspect ratio unless told to stretch: a portrait phone video is not squashed
into a landscape frame, in the camera node and in the bench (issue: the camera stretched frames)."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from facesculpt.app.bench import SIZE, bench_size
from facesculpt.nodes.camera.sources import resize_frame, resized_size


@pytest.mark.parametrize("mode, want", [("fit", (270, 480)), ("fill", (856, 480)), ("stretch", (856, 480))])
def test_a_portrait_frame_in_a_landscape_box(mode, want):
    portrait = np.zeros((1280, 720, 3), np.uint8)
    portrait[:, 300:420] = 255  # a vertical bar in the middle: its width tells the aspect ratio
    out = resize_frame(portrait, 856, 480, mode)
    assert out.shape[:2] == (want[1], want[0])
    bar = (out[out.shape[0] // 2, :, 0] > 127).sum()
    if mode == "stretch":
        assert bar > 120  # widened: the squashed frame the issue complained of
    else:
        scale = out.shape[0] / 1280 if mode == "fit" else out.shape[1] / 720
        assert abs(bar - 120 * scale) <= 2  # aspect kept: the bar scaled like everything else


def test_one_side_given_keeps_the_aspect_and_none_keeps_the_frame():
    assert resized_size(1280, 720, 856, 0) == (856, 482)
    assert resized_size(720, 1280, 0, 480) == (270, 480)
    frame = np.zeros((10, 20, 3), np.uint8)
    assert resize_frame(frame, 0, 0) is frame
    with pytest.raises(ValueError, match="resize mode 'squash' is not one of fit, fill, stretch"):
        resized_size(20, 10, 5, 5, "squash")


def test_fill_crops_the_centre():
    frame = np.zeros((100, 200, 3), np.uint8)
    frame[:, 50:150] = 200  # the centre half
    out = resize_frame(frame, 50, 50, "fill")
    assert out.shape == (50, 50, 3) and (out == 200).all()


def test_the_bench_keeps_the_papers_pixel_count_at_the_inputs_aspect():
    assert bench_size(1280, 720) == SIZE  # within 1 % of the paper's aspect: its exact size
    w, h = bench_size(720, 1280)
    assert w < h and abs(w / h - 720 / 1280) < 0.01 and abs(w * h / (SIZE[0] * SIZE[1]) - 1) < 0.01
    w, h = bench_size(512, 512)
    assert abs(w - h) <= 2 and w % 2 == 0 and h % 2 == 0


def _portrait_video(src, path, frames: int) -> None:
    cap = cv2.VideoCapture(str(src))
    writer = None
    for _ in range(frames):
        ok, frame = cap.read()
        assert ok
        h, w = frame.shape[:2]
        x0 = (w - h * 9 // 16) // 2  # the centre 9:16 strip, upright, at a phone's 720x1280
        frame = cv2.resize(frame[:, x0:x0 + h * 9 // 16], (720, 1280), interpolation=cv2.INTER_CUBIC)
        if writer is None:
            writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 25, frame.shape[1::-1])
        writer.write(frame)
    writer.release()
    cap.release()


@pytest.mark.slow
def test_bench_finds_the_face_in_a_portrait_video(data_dir, models_dir, tmp_path):
    video = tmp_path / "portrait.mp4"
    _portrait_video(data_dir / "video" / "d3.mp4", video, 12)
    out = tmp_path / "bench.json"
    result = subprocess.run(
        [sys.executable, "-m", "facesculpt.cli", "bench", "--video", str(video), "--model", "facemesh",
         "--frames", "6", "--drags", "2", "--no-graph", "--json", str(out)],
        cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    doc = json.loads(out.read_text())
    w, h = doc["size"]
    assert w < h, doc["size"]  # portrait stays portrait
    assert doc["models"]["facemesh"]["stages_ms"]["landmark_detection"] > 0
