"""The sparse fit's rotation prior from the landmark network's own 3D points
(facesculpt/nodes/fitter/detector_rotation.py): the pose solve's prior term, the network's rotation in the
model's head frame, and a nodding head whose detected landmarks lag its pitch, as the face-mesh
network's do."""

from __future__ import annotations

import numpy as np
import pytest

from facesculpt.geometry.projection import project
from facesculpt.nodes.fitter import FitterConfig, load_model, make_fitter
from facesculpt.nodes.fitter.detector_rotation import DetectorRotation
from facesculpt.nodes.fitter.pose import perspective, rotation_from_euler, rotation_log

K = np.array([[560.0, 0, 320], [0, 560.0, 240], [0, 0, 1]])


def test_the_pose_solve_moves_toward_its_rotation_prior_by_its_weight():
    rng = np.random.default_rng(1)
    X = rng.normal(0, 40, (30, 3))
    R_true, t = rotation_from_euler(10, -5, 2), np.array([5.0, -3.0, 600.0])
    x = project(X @ R_true.T + t, K)
    R_prior = rotation_from_euler(10, 5, 2)   # 10 degrees of pitch off
    free, _ = perspective(X, x, K)
    weak, _ = perspective(X, x, K, rotation_prior=(R_prior, 10.0))
    strong, _ = perspective(X, x, K, rotation_prior=(R_prior, 1e5))
    off = [np.degrees(np.linalg.norm(rotation_log(R.T @ R_true))) for R in (free, weak, strong)]
    assert off[0] < 1e-3                      # exact points: the landmarks alone find the pose
    assert 0.0 < off[1] < 2.0 and off[2] > 9.5  # the prior pulls by its weight
    # Weighted about the model's x axis only, a prior that differs in yaw does not move the pose.
    R_yawed = rotation_from_euler(20, -5, 2)
    held, _ = perspective(X, x, K, rotation_prior=(R_yawed, (1e5, 0.0, 0.0)))
    assert np.degrees(np.linalg.norm(rotation_log(held.T @ R_true))) < 0.05


def test_the_network_rotation_is_learned_in_the_model_frame():
    """Points of one head turning (camera axes, pixel scale), seen in a head frame 8 degrees off
    the model's: once the reference and the offset are learned, the prior is the model's rotation."""
    rng = np.random.default_rng(2)
    head = rng.normal(0, 30, (13, 3))
    frame_offset = rotation_from_euler(0, 8, 0)
    net = DetectorRotation(reference_frames=10, offset_frames=100)
    errors = []
    for i in range(60):
        R_model = rotation_from_euler(20 * np.sin(i / 7), 10 * np.sin(i / 5), 3 * np.sin(i / 3))
        pts = head @ (R_model @ frame_offset).T * 1.3 + [320, 240, 0] + rng.normal(0, 0.3, head.shape)
        R_network = net.observe(pts)
        prior = net.prior(R_network)
        if prior is not None:
            errors.append(np.degrees(np.linalg.norm(rotation_log(prior.T @ R_model))))
        net.learn(R_network, R_model)
    assert len(errors) >= 45 and max(errors) < 1.0, max(errors)
    assert net.observe(np.full((13, 3), np.nan)) is None
    net.reset()
    assert net.prior(np.eye(3)) is None   # nothing learned: no prior


def test_the_offset_can_leave_out_the_first_frames_landmark_pitch():
    """A landmark fit 7 degrees off in pitch over its first 30 frames (the identity not yet learned)
    and right afterwards: the fading mean keeps that pitch in the prior long after; with the first
    frames left out (settle_frames) the prior is the model's rotation."""
    rng = np.random.default_rng(3)
    head = rng.normal(0, 30, (13, 3))
    late = {}
    for settle in (0, 30):
        net = DetectorRotation(reference_frames=10, offset_frames=300, settle_frames=settle)
        errors = []
        for i in range(120):
            R_model = rotation_from_euler(20 * np.sin(i / 7), 10 * np.sin(i / 5), 0)
            pts = head @ R_model.T * 1.3 + [320, 240, 0] + rng.normal(0, 0.3, head.shape)
            R_network = net.observe(pts)
            prior = net.prior(R_network)
            if prior is not None and i >= 90:
                errors.append(np.degrees(np.linalg.norm(rotation_log(prior.T @ R_model))))
            landmarks = R_model @ rotation_from_euler(0, 7, 0) if i < 30 else R_model
            net.learn(R_network, landmarks)
        late[settle] = float(np.mean(errors))
    assert late[0] > 1.5 and late[30] < 0.5, late


def test_the_offset_is_relearned_from_the_kept_frames_fitted_again():
    """The same biased first 30 frames, kept (records) and relearned after frame 40 with their
    right rotations: the fading mean is the one of a fit that was right from the start, exactly,
    and the prior between the biased frames and the relearning is still given."""
    rng = np.random.default_rng(4)
    head = rng.normal(0, 30, (13, 3))
    truth = [rotation_from_euler(20 * np.sin(i / 7), 10 * np.sin(i / 5), 0) for i in range(120)]
    points = [head @ R.T * 1.3 + [320, 240, 0] + rng.normal(0, 0.3, head.shape) for R in truth]
    right = DetectorRotation(reference_frames=10, offset_frames=300)
    relearned = DetectorRotation(reference_frames=10, offset_frames=300, keep_frames=40)
    R_networks, held = {}, []
    for i, (pts, R_model) in enumerate(zip(points, truth)):
        R_network = right.observe(pts)
        assert np.allclose(relearned.observe(pts), R_network)
        R_networks[i] = R_network
        right.learn(R_network, R_model)
        relearned.learn(R_network, R_model @ rotation_from_euler(0, 7, 0) if i < 30 else R_model, record=i)
        if i == 40:
            kept = relearned.kept
            assert kept == list(range(40)) and not relearned.relearned   # the first keep_frames frames
            held.append(relearned.prior(R_network))
            relearned.relearn([truth[k] for k in kept])
            assert relearned.relearned and relearned.kept == []
    assert held[0] is not None   # the prior held before the relearning
    assert np.allclose(relearned._offset_sum, right._offset_sum, atol=1e-9)
    late = [np.degrees(np.linalg.norm(rotation_log(relearned.prior(R_networks[i]).T @ truth[i]))) for i in range(90, 120)]
    assert np.mean(late) < 0.5, np.mean(late)
    with pytest.raises(ValueError, match="one rotation per kept frame"):
        fresh = DetectorRotation(reference_frames=1, keep_frames=5)
        fresh.observe(points[0])
        fresh.learn(np.eye(3), np.eye(3), record="frame 0")
        fresh.relearn([])


def test_the_sparse_fit_relearns_the_offset_once_its_identity_has_settled(data_dir):
    """A person nodding (detected points with the network's depth): kept from the first frame,
    the frames are fitted again once the identity's landmark points move less than
    ``rotation_prior_relearn_mm`` over a frame (after the prior's reference frames), a few a
    frame, and the offset rebuilt once; with a threshold never met, from the cap of
    ``rotation_prior_relearn_frames`` on."""
    from facesculpt.nodes.fitter.sparse_fitter import RELEARN_PER_FRAME

    model = load_model("sfm")
    frames = _nodding_frames(model, 50, np.random.default_rng(5))
    ids = [str(k) for k in range(1, 69)]
    for threshold, cap in ((0.05, 150), (0.0, 30)):
        fitter = make_fitter(model, FitterConfig(smoothing=False, neutral_frames=20, rotation_prior_relearn_frames=cap,
                                                 rotation_prior_relearn_mm=threshold), (640, 480), K)
        when = None
        for i, (pts, _) in enumerate(frames):
            fitter.fit(pts, ids, stamp=i / 25)
            if fitter.network_rotation.relearned:
                when, moved = i, fitter.identity_moved_mm
                break
        if threshold:
            assert when is not None and 20 <= when < 50 and moved <= threshold, (when, moved)
        else:
            assert when == cap - 2 + -(-cap // RELEARN_PER_FRAME), when   # from the 30th frame on
        assert fitter.network_rotation.kept == []
    off = make_fitter(model, FitterConfig(smoothing=False, rotation_prior_relearn_frames=0), (640, 480), K)
    off.fit(frames[0][0], ids, stamp=0.0)
    assert off.network_rotation.kept == [] and not off.network_rotation.relearned


def _nodding_frames(model, frames: int, rng):
    """Detected points of one person nodding and turning: (68, 3) px (x, y; z the relative depth in
    pixels) whose nose points lag the pitch (0.25 px per degree, as the face-mesh network's
    did on the realism set), and the true pitch (degrees)."""
    alpha = rng.uniform(-1, 1, model.num_shape).astype(np.float32)
    V = model.instance(alpha).astype(np.float64)
    idx = model.landmark_index()
    # The jaw's points (outline, no fixed vertex) are left out; the inner mouth corners, which the
    # model has no vertex for, are the outer ones (the network gives every point).
    mouth = {"61": "49", "65": "55"}
    X = np.array([V[idx[mouth.get(str(k), str(k))]] if k > 17 else np.full(3, np.nan) for k in range(1, 69)])
    out = []
    for i in range(frames):
        yaw, pitch = 20 * np.sin(2 * np.pi * i / 60), 12 * np.sin(2 * np.pi * i / 40 + 0.6)
        R = rotation_from_euler(yaw, pitch, 0)
        C = X @ R.T + [0.0, 0.0, 550.0]
        pts = np.column_stack([project(C, K), (C[:, 2] - np.nanmean(C[:, 2])) * K[0, 0] / 550.0])
        pts[27:36, 1] += 0.25 * pitch
        pts += rng.normal(0, [0.7, 0.7, 1.5], pts.shape)   # NaN stays NaN
        out.append((pts, pitch))
    return out


@pytest.mark.slow
def test_the_network_depth_steadies_the_fitted_pitch_of_a_nodding_head(data_dir):
    model = load_model("sfm")
    frames = _nodding_frames(model, 150, np.random.default_rng(3))
    errors = {}
    for weight in (0.0, 100.0):
        fitter = make_fitter(model, FitterConfig(smoothing=False, rotation_prior_px=weight), (640, 480), K)
        e = []
        for i, (pts, pitch) in enumerate(frames):
            r = fitter.fit(pts, [str(k) for k in range(1, 69)], stamp=i / 25)
            e.append(r.yaw_pitch_roll[1] - pitch)
        errors[weight] = np.std(e[60:])
    # The landmarks alone follow the nod short by the points' lag; the network's depth holds it.
    assert errors[100.0] < 0.7 * errors[0.0], errors


@pytest.mark.slow
def test_the_sparse_fit_of_a_filmed_face_takes_the_networks_depth(data_dir, models_dir):
    """The landmark network's 468 points of a real video, through ``fit_landmarks`` as the node and
    the pipeline fit them: the iBUG points keep their depth, so after the reference frames every
    fit is held by the network's rotation; with the prior off, none is."""
    import cv2

    from facesculpt.nodes.camera.intrinsics import intrinsics_from_fov
    from facesculpt.nodes.fitter.result import FitError
    from facesculpt.nodes.fitter.stage import fit_landmarks
    from facesculpt.nodes.landmarks import LandmarkDetector

    detector = LandmarkDetector(models_dir=models_dir)
    capture = cv2.VideoCapture(str(data_dir / "video" / "d0.mp4"))
    faces = []
    while len(faces) < 40:
        ok, frame = capture.read()
        assert ok, "d0.mp4 ended before 40 frames with a face"
        found = detector.detect(frame)
        if found:
            faces.append(found[0].points)
    size = (frame.shape[1], frame.shape[0])
    model = load_model("sfm")
    for weight in (100.0, 0.0):
        fitter = make_fitter(model, FitterConfig(rotation_prior_px=weight, neutral_frames=20), size,
                             intrinsics_from_fov(*size, 60.0))
        for i, points in enumerate(faces):
            assert fit_landmarks(fitter, points[None], [1.0], i / 25).fit is not None
        assert (fitter.network_rotation.offsets_learned == len(faces)) == (weight > 0)
        assert (fitter.network_rotation.prior(np.eye(3)) is not None) == (weight > 0)
    with pytest.raises(FitError, match="rotation_prior_px"):
        FitterConfig(rotation_prior_px=-1.0)
