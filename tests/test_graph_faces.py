"""Several faces through the graph, as a user launches it: two people in one video, every face
fitted (fitter.faces=all) and edited by the deformer's preset, every frame written."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from two_people import write_two_people

REPO = Path(__file__).resolve().parent.parent
FRAMES = 30


@pytest.mark.slow
def test_two_people_both_edited_in_every_frame_of_a_replay(data_dir, models_dir, tmp_path):
    video = tmp_path / "two.mkv"
    inputs = write_two_people(data_dir, video, FRAMES)
    out = tmp_path / "out.mkv"
    r = subprocess.run([sys.executable, "-m", "facesculpt.cli", "launch", "replay", f"camera.source={video}",
                        "landmarks.max_faces=4", "fitter.faces=all", "deformer.preset=chin", "deformer.strength=2",
                        f"renderer.output={out}"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "applied preset chin to face 0" in r.stderr and "applied preset chin to face 1" in r.stderr
    cap = cv2.VideoCapture(str(out))
    written = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        written.append(frame)
    assert len(written) == FRAMES
    for i in (5, FRAMES - 1):
        d = np.abs(written[i].astype(np.int16) - inputs[i].astype(np.int16)).max(axis=2) > 12
        left, right = d[:, :512].sum(), d[:, 512:].sum()
        assert left > 400 and right > 400, (i, left, right)  # both chins moved in the same frame
        assert d[:60].mean() < 0.005  # far from the faces the frame is the input's (up to the codec)
