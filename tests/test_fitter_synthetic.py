"""The fitter on synthetic Surrey-Face-Model faces with known ground truth (tests/synthetic_faces.py):
accuracy against eos-py's fit_shape_and_pose on the same faces, outline correspondences, perspective,
identity accumulation and temporal smoothing."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.eos_peer import EosPeer
from benchmarks.synthetic_faces import (
    landmark_reprojection_error,
    make_face,
    similarity_aligned_error,
)
from facesculpt.nodes.fitter import FitterConfig, load_model, make_fitter
from facesculpt.nodes.fitter import outline as outline_corr
from facesculpt.nodes.fitter.eos_import import sfm_files
from facesculpt.nodes.fitter.fitting import correspondence_points
from facesculpt.nodes.fitter.pose import euler_from_rotation

BINS = [(0, 20), (20, 40), (40, 60)]


@pytest.fixture(scope="module")
def sfm(data_dir):
    return load_model("sfm")


@pytest.mark.slow
def test_fit_is_at_least_as_accurate_as_eos_in_every_yaw_bin(sfm, data_dir):
    """24 faces (8 per |yaw| bin), 5 iterations each, same model, blendshapes, contours and landmarks:
    mean 3D error after similarity alignment and landmark reprojection error <= eos' per bin."""
    pytest.importorskip("eos")
    peer = EosPeer(sfm_files(data_dir), (640, 480), iterations=5)
    fitter = make_fitter(sfm, FitterConfig(iterations=5, smoothing=False, accumulate_identity=False), (640, 480))
    rng = np.random.default_rng(2024)
    for lo, hi in BINS:
        ours, theirs, rep_ours, rep_theirs = [], [], [], []
        for i in range(8):
            yaw = rng.uniform(lo, hi) * (1 if i % 2 else -1)
            f = make_face(sfm, rng, yaw=yaw)
            fitter.reset()
            r = fitter.fit(f.noisy, f.ids)
            V, P = peer.fit(f.noisy, f.ids)
            ours.append(similarity_aligned_error(r.model_vertices, f.vertices))
            theirs.append(similarity_aligned_error(V.astype(np.float32), f.vertices))
            rep_ours.append(landmark_reprojection_error(r.projected, sfm, f.ids, f.noisy))
            rep_theirs.append(landmark_reprojection_error(P, sfm, f.ids, f.noisy))
        assert np.mean(ours) <= np.mean(theirs), f"yaw {lo}-{hi}: 3D error {np.mean(ours):.2f} mm vs eos {np.mean(theirs):.2f}"
        assert np.mean(rep_ours) <= np.mean(rep_theirs), f"yaw {lo}-{hi}: reprojection {np.mean(rep_ours):.2f} px vs eos {np.mean(rep_theirs):.2f}"
        # And in absolute terms: millimetres, a pixel and a half (1 px noise).
        assert np.mean(ours) < 3.5 and np.mean(rep_ours) < 2.0


def _outline_residuals(sfm, mode: str, faces) -> np.ndarray:
    """Pixel distance between each true outline landmark and its model correspondence, with the
    model at the true shape and pose (so only the correspondence search is measured)."""
    fitter = make_fitter(sfm, FitterConfig(outline=mode, smoothing=False), (640, 480))
    out = []
    for f in faces:
        sel = [i for i, k in enumerate(f.ids) if k in fitter._outline_side]
        side = np.array([fitter._outline_side[f.ids[i]] for i in sel])
        none = np.zeros((0, 3), int), np.zeros((0, 3))
        verts, weights, x, _ = fitter._with_outline(none[0], none[1], np.zeros((0, 2)), np.zeros(0), f.clean[sel],
                                                    np.ones(len(sel)), side, f.alpha.astype(float),
                                                    f.beta.astype(float), f.R, f.t, f.s)
        X = correspondence_points(f.vertices.astype(np.float64), verts, weights)
        u = (f.s * X @ f.R.T + f.t)[:, :2]
        out.append(np.linalg.norm(u - x, axis=1))
    return np.concatenate(out)


@pytest.mark.slow
def test_ray_triangle_outline_points_lie_closer_to_the_true_outline_than_vertices(sfm):
    rng = np.random.default_rng(11)
    faces = [make_face(sfm, rng, noise_px=0.0) for _ in range(12)]
    ray = _outline_residuals(sfm, "ray", faces)
    nearest = _outline_residuals(sfm, "nearest", faces)
    assert np.median(ray) < 0.8 * np.median(nearest)
    assert np.median(ray) < 1.0  # px, at about 1.6 px per mm


def test_outline_candidates_exclude_the_nose_and_back_facing_vertices(sfm):
    fitter = make_fitter(sfm, FitterConfig(smoothing=False), (640, 480))
    nose = outline_corr.nose_region(sfm.mean, sfm.landmark_index())
    assert nose[sfm.landmark_index()["31"]] and nose.sum() > 20
    for band in fitter._bands:
        assert not nose[band].any()
    # Frontal: the visible rim of the right band is on the subject's right (image left) edge.
    f = make_face(sfm, np.random.default_rng(1), yaw=0.0, pitch=0.0, roll=0.0, noise_px=0.0)
    C = f.s * f.vertices.astype(np.float64) @ f.R.T + f.t
    vis = outline_corr.visible_candidates(fitter._geometry, C, C[:, :2], False, 20 * f.s, fitter._edge_mm * f.s)
    right = fitter._bands[0][vis[fitter._band_pos[0]]]
    assert len(right) > 10
    assert np.median(C[right, 0]) < np.median(C[:, 0]) - 40


@pytest.mark.slow
def test_perspective_fit_recovers_the_pose(sfm):
    K = np.array([[700.0, 0, 320], [0, 700.0, 240], [0, 0, 1]])
    rng = np.random.default_rng(3)
    fitter = make_fitter(sfm, FitterConfig(smoothing=False, accumulate_identity=False), (640, 480), K)
    assert fitter.projection == "perspective"
    for _ in range(6):
        f = make_face(sfm, rng, K=K, distance_mm=550.0)
        fitter.reset()
        r = fitter.fit(f.noisy, f.ids)
        angle = np.degrees(np.arccos(np.clip((np.trace(r.R @ f.R.T) - 1) / 2, -1, 1)))
        assert angle < 4.0
        # Distance trades against face size (the first shape components), so it is only roughly known.
        assert abs(r.t[2] - f.t[2]) < 0.2 * f.t[2]
        assert landmark_reprojection_error(r.projected, sfm, f.ids, f.noisy) < 2.0
        # Camera-space vertices project to the reported pixels through K.
        p = r.vertices[:, :2] / r.vertices[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]
        np.testing.assert_allclose(p, r.projected, atol=1e-2)


def test_orthographic_pose_angles_follow_the_head(sfm):
    fitter = make_fitter(sfm, FitterConfig(smoothing=False, accumulate_identity=False), (640, 480))
    for yaw, pitch in ((-50, 10), (0, -15), (35, 5)):
        f = make_face(sfm, np.random.default_rng(int(yaw + 100)), yaw=yaw, pitch=pitch, roll=0.0)
        fitter.reset()
        r = fitter.fit(f.noisy, f.ids)
        y, p, _ = r.yaw_pitch_roll
        assert abs(y - yaw) < 5 and abs(p - pitch) < 5
        assert euler_from_rotation(f.R)[0] == pytest.approx(yaw)


@pytest.mark.slow
def test_identity_accumulates_over_frames(sfm):
    """One person, 30 frames of new poses and expressions: the neutral shape learned over the
    frames is closer to the truth than any single frame's estimate on average."""
    alpha = np.random.default_rng(5).uniform(-2, 2, 63).astype(np.float32)
    truth = sfm.instance(alpha)
    frames = [make_face(sfm, np.random.default_rng(200 + i), alpha=alpha) for i in range(30)]
    single = make_fitter(sfm, FitterConfig(smoothing=False, accumulate_identity=False), (640, 480))
    accum = make_fitter(sfm, FitterConfig(smoothing=False, accumulate_identity=True), (640, 480))
    single_err = []
    for i, f in enumerate(frames):
        single.fit(f.noisy, f.ids, stamp=i * 1.0)
        accum.fit(f.noisy, f.ids, stamp=i * 1.0)
        single_err.append(similarity_aligned_error(single.neutral, truth))
    final = similarity_aligned_error(accum.neutral, truth)
    assert final < 0.7 * np.mean(single_err)
    accum.reset()
    assert np.all(accum.neutral == sfm.mean)


@pytest.mark.slow
def test_smoothing_steadies_a_still_face(sfm):
    """A still face with 1 px landmark noise at 30 fps: the One Euro filter cuts the frame-to-frame
    jitter of the pose and of the projected mesh."""
    f = make_face(sfm, np.random.default_rng(8), yaw=20.0, pitch=5.0, roll=0.0, noise_px=0.0)
    jitter = {}
    for smooth in (False, True):
        fitter = make_fitter(sfm, FitterConfig(smoothing=smooth, iterations=3), (640, 480))
        noise = np.random.default_rng(9)
        yaws, proj = [], []
        for i in range(45):
            r = fitter.fit(f.clean + noise.normal(0, 1.0, f.clean.shape), f.ids, stamp=i / 30)
            yaws.append(r.yaw_pitch_roll[0])
            proj.append(r.projected)
        yaws, proj = np.array(yaws[15:]), np.array(proj[15:])
        jitter[smooth] = (np.std(yaws), np.linalg.norm(np.diff(proj, axis=0), axis=2).mean())
    assert jitter[True][0] < 0.5 * jitter[False][0]
    assert jitter[True][1] < 0.5 * jitter[False][1]


@pytest.mark.slow
def test_tracking_iterations_follow_a_turning_head_as_well_as_full_iterations(sfm):
    """A head turning from -40° to +40° yaw over 40 frames at 30 fps, one person, perspective camera:
    warm-started frames with one iteration (the default) fit the landmarks and the yaw nearly as
    well as five iterations every frame."""
    K = np.array([[700.0, 0, 320], [0, 700.0, 240], [0, 0, 1]])
    alpha = np.random.default_rng(11).uniform(-1.5, 1.5, sfm.num_shape).astype(np.float32)
    frames = [make_face(sfm, np.random.default_rng(300 + i), yaw=-40 + 2 * i, pitch=5.0, roll=0.0, K=K,
                        distance_mm=550.0, alpha=alpha, beta_max=0.3) for i in range(41)]
    errors, yaw_errors = {}, {}
    for tracking in ("default", None):
        kw = {} if tracking == "default" else {"tracking_iterations": None}
        fitter = make_fitter(sfm, FitterConfig(smoothing=False, **kw), (640, 480), K)
        assert fitter.tracking_iterations == (1 if tracking else fitter.iterations)
        errs, yerr = [], []
        for i, f in enumerate(frames):
            r = fitter.fit(f.noisy, f.ids, stamp=i / 30)
            errs.append(landmark_reprojection_error(r.projected, sfm, f.ids, f.noisy))
            yerr.append(abs(r.yaw_pitch_roll[0] - euler_from_rotation(f.R)[0]))
        errors[tracking], yaw_errors[tracking] = np.array(errs), np.array(yerr)
    assert errors["default"].mean() < errors[None].mean() + 0.1
    assert errors["default"].max() < 2.0
    assert yaw_errors["default"].max() < 2.5
    with pytest.raises(ValueError, match="tracking_iterations"):
        make_fitter(sfm, FitterConfig(tracking_iterations=0), (640, 480))
