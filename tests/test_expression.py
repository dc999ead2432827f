"""Expression parameters: zero on the neutral, each component moved by its own facial motion,
and on a real video the jaw-open parameter follows the mouth opening the landmark network sees,
with both built-in models; `process --export-params` writes them, one row per frame."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.nodes.fitter.expression import NAMES, expression_parameters, expression_points

REPO = Path(__file__).resolve().parent.parent


def test_neutral_is_zero_and_components_answer_their_own_motion():
    from facesculpt.nodes.fitter import load_model

    m = load_model("facemesh")
    neutral = expression_points(m.mean, True, m.landmark_names, m.landmark_vertices)
    assert len(NAMES) >= 20 and np.allclose(expression_parameters(neutral, neutral), 0.0)
    iod = np.linalg.norm(neutral[36] - neutral[45])
    moved = neutral.copy()
    moved[[65, 66, 67], 1] -= 0.1 * iod  # lower inner lip down: the mouth opens by 10 % IOD
    e = dict(zip(NAMES, expression_parameters(moved, neutral)))
    assert e["jaw_open"] == pytest.approx(10.0, abs=0.01)
    assert all(abs(v) < 1e-6 for k, v in e.items() if k != "jaw_open")
    smile = neutral.copy()
    smile[[48, 54], 1] += 0.05 * iod  # both mouth corners up
    e = dict(zip(NAMES, expression_parameters(smile, neutral)))
    assert e["lip_corner_up_right"] == pytest.approx(5.0, abs=0.01) and e["lip_corner_up_left"] == pytest.approx(5.0, abs=0.01)
    shut = neutral.copy()
    shut[[37, 38], 1] = shut[[41, 40], 1]  # right upper lid down onto the lower lid
    e = dict(zip(NAMES, expression_parameters(shut, neutral)))
    assert e["eye_close_right"] == pytest.approx(1.0, abs=0.05) and abs(e["eye_close_left"]) < 1e-6


@pytest.mark.parametrize("model", ["facemesh", "sfm"])
@pytest.mark.slow
def test_jaw_open_follows_the_mouth_on_a_real_video(model, data_dir, models_dir):
    from facesculpt.app.pipeline import Pipeline
    from facesculpt.geometry import to_ibug68

    cap = cv2.VideoCapture(str(data_dir / "video" / "d3.mp4"))
    jaw, opening = [], []
    with Pipeline(model, fit=FitterConfig(neutral_frames=30)) as pipeline:
        for i in range(150):
            ok, frame = cap.read()
            if not ok:
                break
            fits = pipeline.fit_faces(frame, i / 30.0)
            if not fits:
                continue
            jaw.append(float(fits[0].expression[NAMES.index("jaw_open")]))
            points = to_ibug68(pipeline.detector.results()[0].points)
            opening.append(np.linalg.norm(points[62] - points[66]) / np.linalg.norm(points[36] - points[45]))
    cap.release()
    assert len(jaw) > 100
    assert np.corrcoef(jaw, opening)[0, 1] >= 0.9


@pytest.mark.slow
def test_process_exports_one_row_per_frame(data_dir, models_dir, tmp_path):
    out_csv, out_json = tmp_path / "p.csv", tmp_path / "p.json"
    for path in (out_csv, out_json):
        r = subprocess.run([sys.executable, "-m", "facesculpt.cli", "process", str(data_dir / "video" / "d0.mp4"),
                            "-o", str(tmp_path / f"{path.suffix[1:]}.mp4"), "--export-params", str(path),
                            "--max-frames", "12", "--quiet"], cwd=REPO, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(out_csv.open()))
    assert [int(r["frame"]) for r in rows] == list(range(12))
    assert {"yaw_deg", "tz_mm", *NAMES} <= set(rows[0])
    assert all(r["face"] == "0" and float(r["tz_mm"]) > 0 for r in rows)
    doc = json.loads(out_json.read_text())
    assert doc["columns"] == list(rows[0]) and len(doc["rows"]) == 12
    assert doc["rows"][5]["jaw_open"] == pytest.approx(float(rows[5]["jaw_open"]), abs=1e-3)
    assert not list(tmp_path.glob(".*writing*"))


@pytest.mark.slow
def test_the_sfm_fit_of_exact_landmarks_recovers_the_true_expression(data_dir):
    """bench_expression_synthetic's exact-landmark run, short: the synthetic head's true iBUG points
    (no detector) through the SFM fitter give expression parameters that follow the true ones."""
    if not (data_dir / "sfm").is_dir() or not (data_dir / "video" / "s18.mp4").is_file():
        pytest.skip("needs ../shared/data/sfm and video/s18.mp4")
    from argparse import Namespace

    from benchmarks.bench_expression_synthetic import fit_sequence
    from benchmarks.realism.scene import make_scene
    from facesculpt.nodes.fitter import load_model

    args = Namespace(frames=60, neutral_frames=20, model="sfm")
    run = fit_sequence(args, make_scene(data_dir, frames=args.frames), load_model("sfm"), exact=True)
    truth, fitted = np.array(run["truth"]), np.array(run["fitted"])
    assert len(truth) == 40 and np.isfinite(fitted).all()
    for name in ("jaw_open", "lip_corner_up_right", "brow_inner_up_left", "cheek_puff_right"):
        k = NAMES.index(name)
        assert np.corrcoef(truth[:, k], fitted[:, k])[0, 1] > 0.85, name
    assert np.median(run["snr"]) > 25.0


def test_a_refined_fit_measures_its_expression_against_the_landmark_fit(data_dir):
    """The appearance refinement moves the head off the landmarks; that move is not an expression:
    with the landmark fit carried along (``FitResult.landmark_fit``), a refined fit moved by a few
    pixels reads the same expression as its landmark fit, and without it the move shows as one."""
    if not (data_dir / "sfm").is_dir():
        pytest.skip("needs ../shared/data/sfm")
    import dataclasses

    from facesculpt.geometry.projection import project
    from facesculpt.nodes.camera.intrinsics import intrinsics_from_fov
    from facesculpt.nodes.fitter import FitterConfig, load_model, make_fitter
    from facesculpt.nodes.fitter.expression import face_expression, ibug_vertex_ids

    model = load_model("sfm")
    K = intrinsics_from_fov(640, 480, 60.0)
    beta = np.zeros(model.num_expression)
    beta[3] = 0.6                                       # a smile
    X = model.instance(beta=beta) * np.array([1.0, -1.0, -1.0]) + np.array([0.0, 0.0, 600.0])
    ids = ibug_vertex_ids(False, model.landmark_names, model.landmark_vertices)
    points = project(X[ids], K)
    fitter = make_fitter(model, FitterConfig(smoothing=False), (640, 480), K)
    fit = fitter.fit(points, stamp=0.0)
    neutral = fitter.neutral
    shift = np.array([4.0, -3.0, 0.0])                  # mm: about 4 px at this distance
    moved = dataclasses.replace(fit, vertices=fit.vertices + shift, t=np.asarray(fit.t) + shift,
                                projected=project(fit.vertices + shift, K).astype(np.float32), landmark_fit=fit)
    own = face_expression(fit, model, neutral, points)
    assert np.nanmax(np.abs(face_expression(moved, model, neutral, points) - own)) < 1e-4
    unaware = face_expression(dataclasses.replace(moved, landmark_fit=None), model, neutral, points)
    assert np.nanmax(np.abs(unaware - own)) > 1.0
