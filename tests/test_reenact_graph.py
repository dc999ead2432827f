"""The live reenact graph (facesculpt/launch/reenact.yaml) with two video cameras: a still photo of a closed
mouth (d12's first frame) driven by d3 (its first second, then its wide-open mouth), headless into
a video. Real processes, sockets and networks; the output is measured by the landmark network."""

from __future__ import annotations

import os
import subprocess
import sys

import cv2
import numpy as np
import pytest
from conftest import free_port
from test_reenact import mouth_and_lip_grey


def _read(path, indices=None):
    cap, out, i = cv2.VideoCapture(str(path)), [], 0
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        if indices is None or i in indices:
            out.append(frame)
        i += 1
    cap.release()
    return out


@pytest.mark.slow
def test_driver_opens_the_source_mouth_through_the_graph(data_dir, models_dir, tmp_path):
    from facesculpt.nodes.landmarks import LandmarkDetector

    video = data_dir / "video"
    photo, driver, out = tmp_path / "source.png", tmp_path / "driver.mp4", tmp_path / "live.mp4"
    cv2.imwrite(str(photo), _read(video / "d12.mp4", {0})[0])
    frames = _read(video / "d3.mp4", set(range(30)) | set(range(290, 340)))
    writer = cv2.VideoWriter(str(driver), cv2.VideoWriter_fourcc(*"mp4v"), 30, frames[0].shape[1::-1])
    for frame in frames:
        writer.write(frame)
    writer.release()
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    env = dict(os.environ, FACESCULPT_MASTER=f"tcp://127.0.0.1:{free_port()}", FACESCULPT_RUN_DIR=str(run_dir),
               PYTHONUNBUFFERED="1")
    # 10 frames/s: eight node processes keep up on a 2-core machine (live, a stage that falls behind skips frames).
    result = subprocess.run([sys.executable, "-m", "facesculpt.cli", "launch", "reenact", f"source_camera.source={photo}",
                             f"driver_camera.source={driver}", "source_camera.fps=10", "driver_camera.fps=10",
                             "renderer.window=false", f"renderer.output={out}"],
                            env=env, cwd=tmp_path, capture_output=True, text=True, timeout=180)
    log = result.stdout + result.stderr
    assert result.returncode == 0, log[-3000:]
    assert "it is required, so the graph stops" in log
    rendered = _read(out)
    assert len(rendered) >= 30, log[-3000:]
    detector = LandmarkDetector(models_dir)
    gaps = []
    for frame in rendered:
        detector.reset()
        found = detector.track(frame)
        gaps.append(np.linalg.norm(found[0].points[13, :2] - found[0].points[14, :2]) if found else np.nan)
    gaps = np.array(gaps)
    assert np.nanmin(gaps[:5]) < 4.0  # px: the source's mouth is closed before the driver opens
    assert np.nanmax(gaps) > 20.0, gaps  # and opens wide when the driver's does
    # the renderer (mouth: paint in the launch file) paints the opened mouth dark, not stretched lips
    inside, lip = mouth_and_lip_grey(detector, rendered[int(np.nanargmax(gaps))])
    assert inside < 0.6 * lip, (inside, lip)
