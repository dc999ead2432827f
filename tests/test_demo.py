"""The main job, as README's first command runs it: `facesculpt demo` on the embedded input."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest
from conftest import free_port


@pytest.mark.timing
@pytest.mark.slow
def test_demo_writes_an_edited_video_a_before_after_picture_and_timings(models_dir, tmp_path):
    out = tmp_path / "demo"
    env = dict(os.environ, FACESCULPT_MASTER=f"tcp://127.0.0.1:{free_port()}", FACESCULPT_RUN_DIR=str(tmp_path))
    result = subprocess.run([sys.executable, "-m", "facesculpt.cli", "demo", "--out", str(out), "--frames", "120"],
                            env=env, cwd=tmp_path, capture_output=True, text=True, timeout=180)
    assert result.returncode == 0, result.stderr[-3000:]

    import av

    with av.open(str(out / "demo.mp4")) as video:
        assert sum(1 for _ in video.decode(video=0)) == 120   # every camera frame was written (issue 23)
    assert "(120 frames rendered)" in result.stdout
    log = result.stdout + result.stderr
    # Shutdown: each node says it is stopping once at most, none lost the master while stopping.
    for name in ("camera", "landmarks", "fitter", "deformer", "script", "renderer"):
        assert log.count(f"[facesculpt.{name}] stopping (") <= 1, log[-3000:]
    assert "no master answers" not in log, log[-3000:]
    pair = cv2.imread(str(out / "before_after.png"))
    assert pair.shape == (480, 1280, 3)
    before, after = pair[:, :640].astype(int), pair[:, 640:].astype(int)
    changed = np.abs(after - before).max(axis=2) > 40
    changed[:40, :] = False                                # the labels
    ys, xs = np.nonzero(changed)
    # The scripted edits changed the face (a region of real size) and nothing near the borders.
    assert changed.sum() > 1000
    assert 150 < xs.mean() < 490 and 100 < ys.mean() < 420
    assert not changed[:, :60].any() and not changed[:, -60:].any()

    timing = json.loads((out / "timing.json").read_text())
    assert {"landmarks", "fitter", "deformer", "renderer"} <= set(timing["stages_ms"])
    assert all(v >= 0 for stages in timing["stages_ms"].values() for v in stages.values())
    assert timing["rates_hz"]["renderer"]["camera/image"] > 5
