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


@pytest.mark.slow
def test_round_trip_reproduces_the_fitted_parameters_within_quantisation(coded):
    from facesculpt.coding.fsc import LOG_SCALE_STEP, ROT_STEP, TRANS_STEP, read_stream

    frames, fps, analysis, path, sizes = coded
    with pytest.raises(ValueError, match="needs the triangles"):
        read_stream(path)
    stream = read_stream(path, lambda model: analysis.triangles)
    assert stream.present.tolist() == analysis.present.tolist() and analysis.present.all()
    steps = np.array([ROT_STEP] * 3 + [TRANS_STEP] * 3 + [LOG_SCALE_STEP])
    assert np.all(np.abs(stream.pose - analysis.pose) <= steps / 2 + 1e-9)
    # The expression: the decoded shape against the fitted one, mm per vertex. 12 components of 40
    # frames, int8 coefficients, the basis sent at 100 of the 468 vertices and filled in over the
    # mesh: within a small share of how far the face moves.
    decoded = (stream.arrays["mean"] + stream.coeffs @ stream.arrays["basis"]).reshape(len(frames), -1, 3)
    fitted = analysis.expression
    rms = np.sqrt(((decoded - fitted) ** 2).sum(-1).mean(axis=1))
    moved = np.sqrt((fitted ** 2).sum(-1).mean(axis=1))
    assert moved.mean() > 1.0  # mm: the expression does move, so the checks below mean something
    assert np.all(rms < 0.2 * moved + 0.1), (rms, moved)
    assert np.abs(stream.arrays["neutral"] - analysis.neutral).max() <= 0.01 + 1e-6  # mm, int16 in 0.02 mm
    # with K in the header the keyframe's pixels are not sent: they are its mesh projected
    np.testing.assert_allclose(stream.arrays["key_projected"], analysis.key_fit.projected, atol=0.05)
    np.testing.assert_allclose(stream.arrays["key_vertices"], analysis.key_fit.vertices, atol=0.011)


def test_per_frame_stream_is_within_the_target_bitrate(coded):
    from facesculpt.coding.fsc import record_bytes

    frames, fps, analysis, path, sizes = coded
    assert sizes["stream"] == FRAMES * record_bytes(12) == FRAMES * 27  # what a live link spends
    assert sizes["stream"] * 8 / (FRAMES / fps) / 1000 <= 16.0  # kbit/s of the per-frame stream
    assert sizes["records"] < 0.8 * sizes["stream"]  # the file's records, each column as its change
    assert path.stat().st_size == sizes["total"]


@pytest.mark.slow
def test_decoded_face_resembles_the_input(coded):
    from facesculpt.app.coding import decode_file, face_region_quality

    frames, fps, analysis, path, sizes = coded
    stream, decoder = decode_file(path)
    try:
        psnr = [face_region_quality(decoder.frame(i), frames[i], analysis.projected[i])[0] for i in range(FRAMES)]
    finally:
        decoder.close()
    assert psnr[analysis.key] > 30.0  # the keyframe renders as itself (WebP quality 70)
    assert np.mean(psnr) > 22.0
    # Far from the face nothing moves: the background is the keyframe's still.
    shifted = [face_region_quality(np.roll(frames[i], 12, axis=1), frames[i], analysis.projected[i])[0]
               for i in range(FRAMES)]
    assert np.mean(psnr) > np.mean(shifted) + 3.0  # better than the input moved by 12 px


@pytest.mark.slow
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


@pytest.mark.slow
def test_encode_command_reports_the_bitrate(data_dir, models_dir, tmp_path):
    out = tmp_path / "d0.fsc"
    result = subprocess.run([sys.executable, "-m", "facesculpt.cli", "encode", str(data_dir / "video" / "d0.mp4"),
                             "-o", str(out), "--max-frames", "20", "--neutral-frames", "10", "--quiet"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "per-frame stream 5.40 kbit/s at 25 fps" in result.stderr
    assert out.is_file() and not list(tmp_path.glob(".*writing*"))


def test_a_format_1_stream_still_decodes(coded, tmp_path):
    """Streams written before the compact format (every array whole in one part, keyframe JPEG)."""
    import json
    import struct
    import zlib

    from facesculpt.app.coding import decode_file
    from facesculpt.coding.fsc import V1_ARRAYS, coefficient_steps, pack_records
    from facesculpt.nodes.reenact.expression_basis import expression_basis, expression_coefficients

    frames, fps, analysis, path, sizes = coded
    a = analysis
    mean, basis = expression_basis(a.expression, 12)
    coeffs = expression_coefficients(a.expression, mean, basis)
    steps = np.abs(basis).max(axis=1) / 127.0
    header = {"version": 1, "model": "facemesh", "fps": fps, "frames": FRAMES, "width": a.size[0],
              "height": a.size[1], "key": a.key, "vertices": len(a.neutral), "components": 12,
              "K": np.asarray(a.key_fit.K).tolist(), "coeff_steps": coefficient_steps(coeffs).tolist(),
              "basis_steps": steps.tolist()}
    arrays = {"key_vertices": a.key_fit.vertices, "key_projected": a.key_fit.projected, "neutral": a.neutral,
              "mean": mean, "basis": np.round(basis / steps[:, None])}
    blob = zlib.compress(b"".join(np.ascontiguousarray(arrays[k], d).tobytes() for k, d in V1_ARRAYS.items()))
    jpeg = cv2.imencode(".jpg", a.key_image, [cv2.IMWRITE_JPEG_QUALITY, 80])[1].tobytes()
    old = tmp_path / "old.fsc"
    head = json.dumps(header).encode()
    old.write_bytes(b"FSC1" + b"".join(struct.pack("<I", len(p)) + p for p in (head, jpeg, blob))
                    + pack_records(a.present, a.pose, coeffs, header["coeff_steps"]))
    stream, decoder = decode_file(old)
    try:
        frame = decoder.frame(a.key)
    finally:
        decoder.close()
    np.testing.assert_allclose(stream.arrays["key_projected"], a.key_fit.projected)
    assert frame.shape == frames[0].shape and np.abs(frame.astype(int) - frames[a.key]).mean() < 6.0


def test_encode_help_states_the_formats_keyframe_quality():
    """The help text names the default without importing the stream format (scipy) at start-up."""
    from facesculpt.coding.fsc import KEY_QUALITY

    result = subprocess.run([sys.executable, "-m", "facesculpt.cli", "encode", "--help"], capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 0 and f"(default {KEY_QUALITY})" in " ".join(result.stdout.split())
