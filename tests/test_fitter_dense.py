"""The built-in facemesh model and the dense fit, on real video through the real landmark networks
(needs `facesculpt setup`); and the SFM fitted to the same frames through the iBUG-68 mapping."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facesculpt.nodes.fitter import FitterConfig, load_model, make_fitter
from facesculpt.nodes.fitter.facemesh_model import FACEMESH_EYE_CORNER_MM, FACEMESH_SEMANTIC
from facesculpt.paths import MissingModelsError

FRAMES = 40


@pytest.fixture(scope="module")
def tracked(models_dir, data_dir):
    """(W, H) and the 468 tracked points of the first frames of d3.mp4 (a talking, turning head)."""
    from facesculpt.nodes.landmarks import LandmarkDetector

    detector = LandmarkDetector(models_dir)
    cap = cv2.VideoCapture(str(data_dir / "video" / "d3.mp4"))
    points = []
    while len(points) < FRAMES:
        ok, frame = cap.read()
        if not ok:
            break
        faces = detector.track(frame)
        if faces:
            points.append(np.asarray(faces[0].points, np.float64))
    size = (frame.shape[1], frame.shape[0])
    cap.release()
    assert len(points) == FRAMES
    return size, points


def test_facemesh_needs_the_setup_files(tmp_path, monkeypatch):
    monkeypatch.setenv("FACESCULPT_HOME", str(tmp_path))
    with pytest.raises(MissingModelsError, match="facesculpt setup"):
        load_model("facemesh")


def test_facemesh_model_has_the_named_landmarks(models_dir):
    model = load_model("facemesh")
    assert model.dense and model.num_vertices == 468 and model.triangles.max() == 467
    idx = model.landmark_index()
    for name in ("nose_tip", "chin", "forehead", "left_cheek", "right_cheek", "mouth_left", "mouth_right"):
        assert name in idx
    assert idx["17"] == 17 and len(idx) == 468 + len(FACEMESH_SEMANTIC)


def test_dense_fit_reproduces_the_points_and_learns_a_neutral(tracked):
    size, frames = tracked
    fitter = make_fitter("facemesh", FitterConfig(smoothing=False, neutral_frames=20), size)
    versions = []
    for i, pts in enumerate(frames):
        r = fitter.fit(pts, stamp=i / 25)
        # The network's points are the fitted mesh: every vertex lands on its observation.
        np.testing.assert_allclose(r.projected, pts[:, :2], atol=1e-3)
        assert r.vertices.shape == (468, 3) and r.residual_px < 12
        versions.append(fitter.neutral_version)
    assert versions[19] == 20 and versions[-1] == 20 and fitter.neutral_ready
    neutral = fitter.model.mean
    idx = fitter.model.landmark_index()
    eyes = np.linalg.norm(neutral[idx["left_eye_outer"]] - neutral[idx["right_eye_outer"]])
    assert eyes == pytest.approx(FACEMESH_EYE_CORNER_MM, rel=1e-4)
    p = {k: neutral[idx[k]] for k in idx if not k.isdigit()}
    assert p["nose_tip"][2] == neutral[:, 2].max() or p["nose_tip"][2] > np.percentile(neutral[:, 2], 98)
    assert p["forehead"][1] > p["nose_tip"][1] > p["mouth_left"][1] > p["chin"][1]
    assert p["left_cheek"][0] > 20 > -20 > p["right_cheek"][0]
    # A face is 110-150 mm from chin to forehead at a 90 mm eye-corner distance.
    assert 90 < p["forehead"][1] - p["chin"][1] < 160


def test_dense_and_sfm_fits_agree_on_the_head_pose(tracked, data_dir):
    from facesculpt.geometry import to_ibug68

    size, frames = tracked
    dense = make_fitter("facemesh", FitterConfig(smoothing=False), size)
    sparse = make_fitter(load_model("sfm"), FitterConfig(smoothing=False), size)
    yaw_d, yaw_s, rmse = [], [], []
    for i, pts in enumerate(frames):
        yaw_d.append(dense.fit(pts, stamp=i / 25).yaw_pitch_roll[0])
        r = sparse.fit(to_ibug68(pts), stamp=i / 25)
        yaw_s.append(r.yaw_pitch_roll[0])
        rmse.append(r.residual_px)
    yaw_d, yaw_s = np.array(yaw_d), np.array(yaw_s)
    assert np.ptp(yaw_s) > 10  # the head does turn in these frames
    assert np.corrcoef(yaw_d, yaw_s)[0, 1] > 0.9
    assert np.median(np.abs(yaw_d - yaw_s)) < 6
    assert np.median(rmse) < 6  # px, on a 512x512 video


def test_dense_perspective_vertices_project_onto_the_points(tracked):
    size, frames = tracked
    K = np.array([[size[0], 0, size[0] / 2], [0, size[0], size[1] / 2], [0, 0, 1.0]])
    fitter = make_fitter("facemesh", FitterConfig(smoothing=False), size, K)
    for i, pts in enumerate(frames[:5]):
        r = fitter.fit(pts, stamp=i / 25)
        assert r.projection == "perspective"
        np.testing.assert_allclose(r.projected, pts[:, :2], atol=1e-2)
        # Metric camera space: the face is a few hundred mm away and about 90 mm across the eyes.
        eyes = np.linalg.norm(r.vertices[263] - r.vertices[33])
        assert 70 < eyes < 110 and 150 < r.t[2] < 2000


def test_dense_bad_input_is_refused(tracked):
    from facesculpt.nodes.fitter import FitError

    size, frames = tracked
    fitter = make_fitter("facemesh", FitterConfig(), size)
    with pytest.raises(FitError, match="relative depth"):
        fitter.fit(frames[0][:, :2])
    pts = frames[0].copy()
    pts[:300] = np.nan
    with pytest.raises(FitError, match="at least 234"):
        fitter.fit(pts)


def _lags(frames, size, bound: float) -> list[float]:
    """Per frame, the mean distance of the smoothed fit's pixels from the points, as a share of the face's size."""
    fitter = make_fitter("facemesh", FitterConfig(smooth_max_lag=bound), size)
    lags = []
    for i, pts in enumerate(frames):
        r = fitter.fit(pts, stamp=i / 25)
        side = np.ptp(pts[:, :2], axis=0)
        lags.append(float(np.linalg.norm(r.projected - pts[:, :2], axis=1).mean() / np.sqrt(side[0] * side[1])))
    return lags


def test_smoothed_fit_follows_a_fast_motion_within_its_lag_bound(tracked):
    """A head that jumps 40 px between two frames (a fast shake, as on d12): the smoothed fit keeps
    within ``smooth_max_lag`` of the face's size of the points on every frame; unbounded, it lags
    far behind. A still head with the points' jitter is smoothed as before (the bound does not bind)."""
    size, frames = tracked
    bound = FitterConfig().smooth_max_lag
    moved = [p + (np.array([40.0, 0.0, 0.0]) if i >= 20 else 0.0) for i, p in enumerate(frames)]
    assert max(_lags(moved, size, 0.0)[20:23]) > 2 * bound   # the plain filter lags the jump
    assert max(_lags(moved, size, bound)) < 1.1 * bound     # bounded: every frame, the jump included
    rng = np.random.default_rng(0)
    still = [frames[0] + np.c_[rng.normal(0, 0.3, (len(frames[0]), 2)), np.zeros(len(frames[0]))] for _ in range(20)]
    plain, bounded = _lags(still, size, 0.0), _lags(still, size, bound)
    assert 0 < max(plain) < bound and np.allclose(bounded, plain)
