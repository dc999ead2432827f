"""Model-based coding on a real video (d0, its first frames): the stream's records hold the
fitted parameters within their quantisation, fit the bitrate target, and decode to the face."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest

FRAMES = 40


@pytest.fixture(scope="module")
def coded(data_dir, models_dir, tmp_path_factory):
    from facesculpt.app.coding import analyse, encode

    cap, frames = cv2.VideoCapture(str(data_dir / "video" / "d0.mp4")), []
    while len(frames) < FRAMES:
        ok, frame = cap.read()
        assert ok
        frames.append(frame)
    fps = cap.get(cv2.CAP_PROP_FPS)
    cap.release()
    analysis = analyse(frames, fps, neutral_frames=10)
    path = tmp_path_factory.mktemp("coding") / "d0.fsc"
    sizes = encode(analysis, path, components=12)
    return frames, fps, analysis, path, sizes


def test_round_trip_reproduces_the_fitted_parameters_within_quantisation(coded):
    from facesculpt.msgs.fsc import LOG_SCALE_STEP, ROT_STEP, TRANS_STEP, read_stream

    frames, fps, analysis, path, sizes = coded
    stream = read_stream(path)
    assert stream.present.tolist() == analysis.present.tolist() and analysis.present.all()
    steps = np.array([ROT_STEP] * 3 + [TRANS_STEP] * 3 + [LOG_SCALE_STEP])
    assert np.all(np.abs(stream.pose - analysis.pose) <= steps / 2 + 1e-9)
    # The expression: the decoded shape against the fitted one, mm. 12 components of 40 frames,
    # int8 coefficients and an int8 basis: within a few hundredths of a mm RMS.
    decoded = stream.arrays["mean"] + stream.coeffs @ stream.arrays["basis"]
    fitted = analysis.expression.reshape(len(frames), -1)
    rms = np.sqrt(((decoded - fitted) ** 2).mean(axis=1))
    assert rms.max() < 0.1, rms.max()
    assert np.abs(fitted).max() > 1.0  # the expression does move (mm), so the check above means something
    assert np.abs(stream.arrays["neutral"] - analysis.neutral).max() < 0.05  # mm, float16


def test_per_frame_stream_is_within_the_target_bitrate(coded):
    from facesculpt.msgs.fsc import record_bytes

    frames, fps, analysis, path, sizes = coded
    assert sizes["records"] == FRAMES * record_bytes(12) == FRAMES * 27
    assert sizes["records"] * 8 / (FRAMES / fps) / 1000 <= 16.0  # kbit/s of the per-frame stream
    assert path.stat().st_size == sizes["total"]


def test_decoded_face_resembles_the_input(coded):
    from facesculpt.app.coding import decode_file, face_region_quality

    frames, fps, analysis, path, sizes = coded
    stream, decoder = decode_file(path)
    try:
        psnr = [face_region_quality(decoder.frame(i), frames[i], analysis.projected[i])[0] for i in range(FRAMES)]
    finally:
        decoder.close()
    assert psnr[analysis.key] > 30.0  # the keyframe renders as itself (JPEG quality 80)
    assert np.mean(psnr) > 22.0
    # Far from the face nothing moves: the background is the keyframe's still.
    shifted = [face_region_quality(np.roll(frames[i], 12, axis=1), frames[i], analysis.projected[i])[0]
               for i in range(FRAMES)]
    assert np.mean(psnr) > np.mean(shifted) + 3.0  # better than the input moved by 12 px


def test_commands_round_trip(coded, tmp_path):
    frames, fps, analysis, path, sizes = coded
    run = [sys.executable, "-m", "facesculpt.cli"]
    video = tmp_path / "out.mp4"
    result = subprocess.run([*run, "decode", str(path), "-o", str(video), "--quiet"], capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    cap = cv2.VideoCapture(str(video))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == FRAMES
    cap.release()
    bad = tmp_path / "bad.fsc"
    bad.write_bytes(video.read_bytes())
    result = subprocess.run([*run, "decode", str(bad), "-o", str(tmp_path / "x.mp4"), "--quiet"],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode != 0 and "not a facesculpt coded stream" in result.stderr
    assert not (tmp_path / "x.mp4").exists()


def test_encode_command_reports_the_bitrate(data_dir, models_dir, tmp_path):
    out = tmp_path / "d0.fsc"
    result = subprocess.run([sys.executable, "-m", "facesculpt.cli", "encode", str(data_dir / "video" / "d0.mp4"),
                             "-o", str(out), "--max-frames", "20", "--neutral-frames", "10", "--quiet"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "per-frame stream 5.40 kbit/s at 25 fps" in result.stderr
    assert out.is_file() and not list(tmp_path.glob(".*writing*"))
