"""`facesculpt reenact` on real videos: a closed-mouth source (d12's first frame) driven by d3,
whose mouth opens wide near its end. The output is measured by the landmark network itself."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest

from facesculpt.nodes.fitter.config import FitterConfig


def _frames(path, indices):
    cap, out, i = cv2.VideoCapture(str(path)), [], 0
    want = set(indices)
    while len(out) < len(want):
        ok, frame = cap.read()
        if not ok:
            break
        if i in want:
            out.append(frame)
        i += 1
    cap.release()
    return out


def _inner_lip_gap(detector, frame) -> float:
    """Distance (px) between the face mesh's inner upper and lower lip midpoints (13, 14)."""
    detector.reset()
    found = detector.track(frame)
    assert found, "no face in the reenacted frame"
    p = found[0].points
    return float(np.linalg.norm(p[13, :2] - p[14, :2]))


def mouth_and_lip_grey(detector, frame) -> tuple[float, float]:
    """Mean grey just inside the mouth's centre and on the lower lip's outer midpoint of ``frame``
    (face-mesh points 13/14 and 17, found by ``detector``): an opened mouth painted dark has the
    first well under the second."""
    gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY).astype(np.float64)
    detector.reset()
    p = detector.track(frame)[0].points
    centre = (p[13, :2] + p[14, :2]) / 2
    inside = gray[int(centre[1]) + 2, int(centre[0]) - 3:int(centre[0]) + 4].mean()
    lip = gray[int(p[17, 1]), int(p[17, 0]) - 3:int(p[17, 0]) + 4].mean()
    return float(inside), float(lip)


@pytest.mark.slow
def test_output_mouth_opens_when_the_drivers_does(data_dir, models_dir):
    from facesculpt.app.pipeline import Pipeline
    from facesculpt.app.reenactment import Reenactor, fit_source, inner_lip_ids
    from facesculpt.nodes.landmarks import LandmarkDetector
    from facesculpt.nodes.renderer.mouth_interior import opening_px

    video = data_dir / "video"
    source = fit_source(_frames(video / "d12.mp4", [0])[0])
    driving = _frames(video / "d3.mp4", list(range(20)) + list(range(280, 354, 2)))
    pipe = Pipeline("facemesh", fit=FitterConfig(neutral_frames=20))
    pipe.calibrate(driving[:20], 30.0)
    assert opening_px(source.fit.projected[inner_lip_ids(pipe.model)]) < 3.0  # the source's mouth is closed
    reenactor = Reenactor(source, pipe.model, pipe.neutral)
    jaw, outputs = [], []
    try:
        for i, frame in enumerate(driving[20:]):
            fit = pipe.fit_frame(frame, i / 15.0)
            assert fit is not None
            jaw.append(fit.expression[0])
            outputs.append(reenactor.render(fit))
    finally:
        reenactor.close()
        pipe.close()
    detector = LandmarkDetector(models_dir)
    gaps = np.array([_inner_lip_gap(detector, out) for out in outputs])
    jaw = np.array(jaw)
    assert jaw.max() - jaw.min() > 15.0  # the driver does open its mouth (%IOD)
    assert np.corrcoef(jaw, gaps)[0, 1] >= 0.8
    assert gaps[jaw.argmax()] - gaps[jaw.argmin()] > 8.0  # px, on a face about 120 px between the eyes
    # The painted interior is dark: inside the opened mouth, much darker than the lips around it.
    inside, lip = mouth_and_lip_grey(detector, outputs[int(jaw.argmax())])
    assert inside < 0.6 * lip


@pytest.mark.slow
def test_command_writes_one_frame_per_driving_frame(data_dir, models_dir, tmp_path):
    video = data_dir / "video"
    out = tmp_path / "avatar.mp4"
    cmd = [sys.executable, "-m", "facesculpt.cli", "reenact", "--source", str(video / "d12.mp4"),
           "--driving", str(video / "d0.mp4"), "-o", str(out), "--max-frames", "25", "--neutral-frames", "10",
           "--side-by-side", "--pose", "--quiet"]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "wrote 25 frames" in result.stderr
    cap = cv2.VideoCapture(str(out))
    n, ok, frame = 0, True, None
    while ok:
        ok, f = cap.read()
        if ok:
            n, frame = n + 1, f
    assert n == 25 and frame.shape[:2] == (512, 3 * 512)
    assert not list(tmp_path.glob(".*writing*"))  # the staged file was renamed


def test_command_refuses_to_write_over_its_inputs(data_dir, tmp_path):
    video = tmp_path / "d0.mp4"
    video.write_bytes((data_dir / "video" / "d0.mp4").read_bytes())
    before = video.read_bytes()
    cmd = [sys.executable, "-m", "facesculpt.cli", "reenact", "--driving", str(video), "-o", str(video), "--quiet"]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert result.returncode != 0 and "refusing" in result.stderr
    assert video.read_bytes() == before


@pytest.mark.parametrize("bad", [["--neutral-frames", "0"], ["--max-frames", "-1"]])
def test_bad_options_say_so(bad, tmp_path):
    cmd = [sys.executable, "-m", "facesculpt.cli", "reenact", "--driving", "x.mp4", "-o", str(tmp_path / "o.mp4"), *bad]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert result.returncode != 0 and "must be" in result.stderr
