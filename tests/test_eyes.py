"""Irises (MediaPipe's iris network on the face mesh's eye crops), the gaze geometry, the messages
that carry them and the nodes that publish them (issue 48)."""

from __future__ import annotations

import time
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from facesculpt.geometry.eye_points import MESH_EYE_LIDS, eye_opening
from facesculpt.msgs import FaceGaze, FaceLandmarks, Image, decode, encode
from facesculpt.nodes.fitter.gaze import (
    EYEBALL_RADIUS_MM,
    IRIS_RADIUS_MM,
    EyeballLearning,
    direction_from_angles,
    estimate_gaze,
    yaw_pitch,
)


@pytest.fixture(scope="module")
def d0_faces(models_dir, data_dir):
    """Frames 20..25 of d0.mp4 and the face mesh's points on each."""
    from facesculpt.nodes.landmarks import LandmarkDetector

    detector = LandmarkDetector(models_dir)
    cap = cv2.VideoCapture(str(data_dir / "video" / "d0.mp4"))
    out = []
    for i in range(26):
        ok, frame = cap.read()
        assert ok
        faces = detector.track(frame)
        if i >= 20 and faces:
            out.append((frame, faces[0].points))
    cap.release()
    assert out
    return out


@pytest.fixture(scope="module")
def irises(models_dir):
    from facesculpt.nodes.landmarks.irises import IrisDetector

    return IrisDetector(models_dir)


def test_irises_lie_in_their_own_eyes_and_the_lids_on_the_mesh(d0_faces, irises):
    for frame, points in d0_faces:
        found, lids = irises.find(frame, points)
        assert found.shape == (2, 5, 3) and lids.shape == (2, 16, 3) and found.dtype == np.float32
        for e in (0, 1):
            mesh_lids = points[list(MESH_EYE_LIDS[e]), :2]
            width = np.linalg.norm(mesh_lids[0] - mesh_lids[8])
            polygon = mesh_lids[[0, 1, 2, 3, 4, 5, 6, 7, 8, 15, 14, 13, 12, 11, 10, 9]].astype(np.float32)
            # the iris centre inside the eye's opening (a little slack: the lids cover part of the iris)
            assert cv2.pointPolygonTest(polygon, tuple(map(float, found[e, 0, :2])), True) > -0.05 * width
            assert np.median(np.linalg.norm(lids[e, :, :2] - mesh_lids, axis=1)) < 0.15 * width
            radius = np.linalg.norm(found[e, 1:, :2] - found[e, 0, :2], axis=1)
            assert 0.12 * width < radius.mean() < 0.4 * width  # an iris about a third of the eye wide
        assert found[0, 0, 0] < found[1, 0, 0]  # the right eye is on the image's left
        assert 0.15 < eye_opening(lids).min() and eye_opening(lids).max() < 0.6  # open eyes


def test_both_eyes_in_one_batch_give_what_each_gives_alone(d0_faces, irises):
    from facesculpt.nodes.landmarks.irises import eye_inputs

    frame, points = d0_faces[0]
    assert irises.batched  # setup gave the network a free batch axis
    x, _ = eye_inputs(frame, points[:, :2] + 0.5)
    both = irises.net.run(x)
    for e in (0, 1):
        alone = irises.net.run(x[e:e + 1])
        for a, b in zip(both, alone):
            np.testing.assert_allclose(a[e], b[0], atol=1e-3)


def test_the_converted_iris_network_matches_the_original(d0_faces, models_dir):
    pytest.importorskip("ai_edge_litert")
    from facesculpt.nodes.landmarks.irises import IrisDetector

    litert = IrisDetector(models_dir, backend="litert")
    onnx = IrisDetector(models_dir)
    frame, points = d0_faces[0]
    for a, b in zip(onnx.find(frame, points), litert.find(frame, points)):
        assert np.abs(a[..., :2] - b[..., :2]).max() < 0.05  # pixels


# -- the gaze geometry, on eyes built as the model says ---------------------------------------------
def _head(yaw_deg: float) -> np.ndarray:
    """Model-to-camera rotation of a head turned ``yaw_deg`` (model: x left, y up, z out)."""
    a = np.radians(yaw_deg)
    turn = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    return turn @ np.diag([1.0, -1.0, -1.0])


K = np.array([[900.0, 0, 320.0], [0, 900.0, 240.0], [0, 0, 1]])
OPENINGS = np.array([[-32.0, 35.0, 10.0], [32.0, 35.0, 10.0]])  # model mm


def _frame(R, t, eye_dirs, closed=(False, False)):
    """(fit, lid vertices, irises px, lids px) of eyes whose opening centres are OPENINGS and whose
    limbus circles turn about the centres the estimator assumes, looking along ``eye_dirs`` (2, 3)
    model space."""
    depth = np.sqrt(EYEBALL_RADIUS_MM ** 2 - IRIS_RADIUS_MM ** 2)
    # the lids in the network's order: the lower lid from the outer corner (0) to the inner (8),
    # then the upper lid (9..15); the right eye's outer corner is at -x
    a = np.pi * np.r_[np.arange(9), np.arange(1, 8)] / 8
    sign = np.r_[-np.ones(9), np.ones(7)]
    lid_model = np.concatenate([o + np.column_stack([s * 14 * np.cos(a), sign * 5 * np.sin(a), 0 * a])
                                for o, s in zip(OPENINGS, (-1.0, 1.0))])
    to_cam = lambda X: X @ R.T + t  # noqa: E731
    proj = lambda X: (to_cam(X) / to_cam(X)[:, 2:3]) @ K.T  # noqa: E731
    irises, lids = np.zeros((2, 5, 3)), np.zeros((2, 16, 3))
    for e in (0, 1):
        centre = OPENINGS[e] - depth * np.array([0, 0, 1.0])
        d = eye_dirs[e] / np.linalg.norm(eye_dirs[e])
        iris_centre = centre + depth * d
        side = np.cross([0, 1.0, 0], d)
        side /= np.linalg.norm(side)
        up = np.cross(d, side)
        ring = [iris_centre] + [iris_centre + IRIS_RADIUS_MM * v for v in (side, up, -side, -up)]
        irises[e, :, :2] = proj(np.array(ring))[:, :2]
        lids[e, :, :2] = proj(lid_model[16 * e: 16 * e + 16])[:, :2]
        if closed[e]:  # both lids on the line between the corners
            lids[e, 1:8, :2] = lids[e, 9:16, :2] = (lids[e, 0, :2] + lids[e, 8, :2]) / 2
    fit = SimpleNamespace(R=R, t=t, scale=1.0, projection="perspective", K=K, model_vertices=lid_model)
    return fit, (np.arange(16), np.arange(16, 32)), irises, lids


def test_gaze_recovers_known_directions_at_turned_heads():
    state = EyeballLearning(learn_frames=10)
    rng = np.random.default_rng(3)
    errors = []
    for i in range(40):
        yaw = 25.0 * np.sin(i / 6.0)
        R, t = _head(yaw), np.array([10.0, -5.0, 550.0])
        target = direction_from_angles(*rng.uniform(-20, 20, 2), camera=False)
        fit, lid_v, irises, lids = _frame(R, t, np.stack([target, target]))
        g = estimate_gaze(fit, lid_v, irises, lids, state)
        assert not g.closed.any()
        if g.learned:
            errors.append(np.degrees(np.arccos(np.clip(g.direction @ (R @ target), -1, 1))))
            np.testing.assert_allclose([g.head_yaw_deg, g.head_pitch_deg], yaw_pitch(target, camera=False), atol=1.5)
    assert state.learned and len(errors) >= 25
    assert np.mean(errors) < 1.0 and abs(state.iris_radius() - IRIS_RADIUS_MM) < 0.3


def test_converging_eyes_give_vergence_and_the_fixated_point():
    state = EyeballLearning(learn_frames=1)
    R, t = _head(0.0), np.array([0.0, 0.0, 550.0])
    depth = np.sqrt(EYEBALL_RADIUS_MM ** 2 - IRIS_RADIUS_MM ** 2)
    centres = OPENINGS - depth * np.array([0, 0, 1.0])
    point = np.array([0.0, 20.0, 300.0])  # model mm, in front of the face
    fit, lid_v, irises, lids = _frame(R, t, point - centres)
    estimate_gaze(fit, lid_v, irises, lids, state)
    g = estimate_gaze(fit, lid_v, irises, lids, state)
    want = np.degrees(np.arccos((point - centres[0]) @ (point - centres[1]) / np.prod(np.linalg.norm(point - centres, axis=1))))
    assert g.vergence_deg > 0 and abs(g.vergence_deg - want) < 1.0
    assert np.linalg.norm(g.fixation - (R @ point + t)) < 15.0


def test_a_closed_eye_is_flagged_and_its_gaze_not_guessed():
    state = EyeballLearning(learn_frames=5)
    R, t = _head(10.0), np.array([0.0, 0.0, 550.0])
    ahead = np.array([[0, 0, 1.0], [0, 0, 1.0]])
    for _ in range(8):
        g = estimate_gaze(*_frame(R, t, ahead), state)
    assert not g.closed.any() and np.isfinite(g.direction).all()
    g = estimate_gaze(*_frame(R, t, ahead, closed=(True, False)), state)
    assert list(g.closed) == [True, False] and np.isnan(g.directions[0]).all() and g.confidences[0] == 0
    assert np.isfinite(g.direction).all() and np.isnan(g.vergence_deg) and not g.blink
    g = estimate_gaze(*_frame(R, t, ahead, closed=(True, True)), state)
    assert g.blink and np.isnan(g.direction).all() and g.confidence == 0 and np.isnan(g.yaw_deg)


# -- messages, nodes, export, drawing ---------------------------------------------------------------
def test_landmarks_without_irises_still_decode_and_gaze_round_trips():
    msg = FaceLandmarks(points=np.zeros((1, 468, 3), np.float32), scores=np.ones(1, np.float32),
                        rois=np.zeros((1, 5), np.float32), K=np.eye(3))
    _, back = decode(encode(msg, "face/landmarks"))
    assert back.irises is None and back.eye_lids is None  # an older message: no eyes, nothing lost
    msg.irises, msg.eye_lids = np.ones((1, 2, 5, 3), np.float32), np.ones((1, 2, 16, 3), np.float32)
    _, back = decode(encode(msg, "face/landmarks"))
    assert back.irises.shape == (1, 2, 5, 3) and back.eye_lids.shape == (1, 2, 16, 3)
    msg.irises = np.ones((1, 2, 4, 3), np.float32)  # malformed: dropped by the decoder
    from facesculpt.msgs import DecodeError

    with pytest.raises(DecodeError):
        decode(encode(msg, "face/landmarks"))


def test_nodes_publish_irises_and_gaze(d0_faces, models_dir, monkeypatch, tmp_path):
    from facesculpt.nodes.fitter.node import FitterNode
    from facesculpt.nodes.landmarks.node import LandmarksNode

    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    landmarks = LandmarksNode(params={"models_dir": str(models_dir), "irises": True})
    landmarks.setup()
    sent = []
    landmarks.pub.publish = sent.append
    fitter = FitterNode(params={"neutral_frames": 3})
    fitter.setup()
    gazes = []
    fitter.gaze_pub.publish = gazes.append
    try:
        h, w = d0_faces[0][0].shape[:2]
        K = np.array([[w, 0, w / 2], [0, w, h / 2], [0, 0, 1.0]])
        for i, (frame, _) in enumerate(d0_faces):
            landmarks.on_image(Image(stamp=i + 1, seq=i + 1, frame_id="camera", image=frame, K=K))
            _, back = decode(encode(sent[-1], "face/landmarks"))
            fitter.on_landmarks(back)
    finally:
        landmarks.close()
        fitter.close()
    assert all(m.irises.shape == (1, 2, 5, 3) and m.eye_lids.shape == (1, 2, 16, 3) for m in sent)
    assert len(gazes) == len(d0_faces) and fitter.errors == 0
    _, g = decode(encode(gazes[-1], "face/gaze"))
    assert isinstance(g, FaceGaze) and g.stamp == len(d0_faces) and g.centres.shape == (2, 3)
    assert np.isfinite(g.direction).all() and abs(np.linalg.norm(g.direction) - 1) < 1e-4
    assert np.all(g.closed == 0) and -60 < g.angles[0] < 60 and g.centres[0, 0] < g.centres[1, 0]


def test_export_writes_the_gaze_columns(tmp_path):
    from facesculpt.app.params_export import ParamsExport
    from facesculpt.nodes.fitter.gaze import GAZE_NAMES

    state = EyeballLearning(learn_frames=1)
    R, t = _head(0.0), np.array([0.0, 0.0, 550.0])
    fit, lid_v, irises, lids = _frame(R, t, np.array([[0, 0, 1.0], [0, 0, 1.0]]))
    fit.t, fit.gaze, fit.expression = t, estimate_gaze(fit, lid_v, irises, lids, state), None
    fit.yaw_pitch_roll = (0.0, 0.0, 0.0)
    export = ParamsExport(tmp_path / "p.csv", gaze=True)
    export.add(0, 0.0, {0: fit})
    export.add(1, 0.04, {})
    text = export.write().read_text().splitlines()
    header = text[0].split(",")
    assert header[-len(GAZE_NAMES):] == list(GAZE_NAMES)
    row = dict(zip(header, text[1].split(",")))
    assert abs(float(row["gaze_head_yaw_deg"])) < 1.0 and row["blink_right"] == "0"
    assert ParamsExport(tmp_path / "q.csv").columns[-1] not in GAZE_NAMES  # without --gaze: as before


def test_draw_gaze_draws_the_rays_and_marks_a_closed_eye():
    from facesculpt.nodes.renderer.gaze_overlay import CLOSED_BGR, RAY_BGR, draw_gaze

    image = np.full((480, 640, 3), 90, np.uint8)
    centres = np.array([[-32.0, -30.0, 560.0], [32.0, -30.0, 560.0]])
    directions = np.array([[0.3, 0.0, -0.95], [np.nan, np.nan, np.nan]])
    out = draw_gaze(image, K, centres, directions, closed=(False, True))
    assert image.max() == 90  # the input is left alone
    ray = np.all(out == RAY_BGR, axis=2)
    bar = np.all(out == CLOSED_BGR, axis=2)
    assert ray.sum() > 50 and bar.sum() > 5
    ys, xs = np.nonzero(ray)
    assert xs.max() - xs.min() > 40  # the ray heads to the image's right (positive x)


@pytest.mark.slow
def test_process_gaze_exports_each_frames_gaze(data_dir, models_dir, tmp_path):
    import csv
    import subprocess
    import sys

    out, params = tmp_path / "out.mp4", tmp_path / "params.csv"
    run = subprocess.run([sys.executable, "-m", "facesculpt.cli", "process", str(data_dir / "video" / "d0.mp4"),
                          "-o", str(out), "--gaze", "--export-params", str(params), "--max-frames", "8", "--quiet"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    rows = list(csv.DictReader(params.open()))
    assert len(rows) == 8 and out.is_file()
    yaw = [float(r["gaze_yaw_deg"]) for r in rows]
    assert all(-60 < y < 60 for y in yaw) and all(r["blink_right"] in ("0", "1") for r in rows)
    assert np.std(yaw) < 10  # one person holding a gaze over a third of a second: no jumps


@pytest.mark.slow
def test_a_fitter_process_publishes_gaze_for_landmarks_with_irises(graph, d0_faces, irises):
    from facesculpt.runtime.node import Node
    from facesculpt.runtime.qos import EVERY_MESSAGE

    msgs = []
    for i, (frame, points) in enumerate(d0_faces):
        h, w = frame.shape[:2]
        found, lids = irises.find(frame, points)
        msgs.append(FaceLandmarks(stamp=1_000_000_000 + i * 40_000_000, seq=i, frame_id="camera",
                                  points=np.asarray(points, np.float32)[None], scores=np.ones(1, np.float32),
                                  rois=np.zeros((1, 5), np.float32), image_size=[w, h],
                                  K=np.array([[w, 0, w / 2], [0, w, h / 2], [0, 0, 1.0]]),
                                  irises=found[None], eye_lids=lids[None]))
    proc = graph.spawn("run", "fitter", "model=facemesh", "neutral_frames=3")
    client = Node(name="gaze_test_client")
    gazes: list[FaceGaze] = []
    pub = client.advertise("face/landmarks", FaceLandmarks)
    client.subscribe("face/gaze", FaceGaze, gazes.append, qos=EVERY_MESSAGE)
    client.start()
    try:
        deadline, k = time.monotonic() + 60, 0
        while len(gazes) < 5 and time.monotonic() < deadline:
            pub.publish(msgs[k % len(msgs)])
            k += 1
            client.spin_once(0.1)
        assert len(gazes) >= 5, f"no face/gaze from the fitter process: {client.diagnostics()}"
        g = gazes[-1]
        assert g.stamp in {m.stamp for m in msgs} and np.isfinite(g.direction).all() and not g.closed.any()
    finally:
        client.close()
        proc.terminate()
        assert proc.wait(10) == 0
