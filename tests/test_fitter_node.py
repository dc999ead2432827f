"""The fitter node: face/landmarks in, face/state and the latched face/model out. In-process
(callbacks called directly, real sockets for publishing) and as a real process in a graph."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest
from conftest import published_into

from facesculpt.msgs import FaceLandmarks, FaceModel, FaceState, Image
from facesculpt.nodes.fitter.node import FitterNode


@pytest.fixture(scope="module")
def captured(models_dir, data_dir):
    """(the frame, its real FaceLandmarks message): the landmark networks on the first 12 frames
    of d0.mp4 with a face."""
    from facesculpt.nodes.landmarks import LandmarkDetector

    detector = LandmarkDetector(models_dir)
    cap = cv2.VideoCapture(str(data_dir / "video" / "d0.mp4"))
    msgs, images = [], []
    while len(msgs) < 12:
        ok, frame = cap.read()
        assert ok
        faces = detector.track(frame)
        if not faces:
            continue
        h, w = frame.shape[:2]
        K = np.array([[w, 0, w / 2], [0, w, h / 2], [0, 0, 1.0]])
        msgs.append(FaceLandmarks(
            stamp=1_000_000_000 + len(msgs) * 40_000_000, seq=len(msgs), frame_id="camera",
            points=np.asarray(faces[0].points, np.float32)[None], scores=np.array([faces[0].score], np.float32),
            rois=np.asarray(faces[0].roi, np.float32).reshape(1, 5), image_size=[w, h], K=K,
        ))
        images.append(frame)
    cap.release()
    return list(zip(images, msgs))


@pytest.fixture(scope="module")
def frames(captured):
    """Real FaceLandmarks messages (:func:`captured`)."""
    return [msg for _, msg in captured]


def test_facemesh_node_fits_frames_and_publishes_the_learned_neutral(monkeypatch, tmp_path, frames):
    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    node = FitterNode(params={"neutral_frames": 6, "model_period_s": 0.1})
    node.setup()  # publishes the placeholder neutral (version 1) before any capture
    out = {"state": published_into(node.state_pub, []), "model": published_into(node.model_pub, [])}
    try:
        for msg in frames:
            node.on_landmarks(msg)
        states = out["state"]
        assert len(states) == len(frames)
        for st, msg in zip(states, frames):
            assert st.stamp == msg.stamp and st.frame_id == msg.frame_id and st.model_id == "facemesh"
            assert st.vertices.shape == (468, 3) and st.projection == "perspective"
            # One Euro smoothing is on: the mesh follows the points within a pixel or two.
            assert np.abs(st.projected - msg.points[0, :, :2]).max() < 3.0
        # The learned neutral went out while it was learned, and once more when complete; then no more.
        models = out["model"]
        assert 1 <= len(models) <= 6 and models[-1].version == node.model_version
        assert [m.version for m in models] == sorted(m.version for m in models)
        assert np.allclose(models[-1].vertices, node.fitter.model.mean) and node.fitter.neutral_ready
        assert models[-1].landmark_names[:2] == ["0", "1"] and "nose_tip" in models[-1].landmark_names
        n = len(models)
        node.on_landmarks(frames[-1])
        assert len(out["model"]) == n
        assert node.counters["fitted"] == len(frames) + 1 and node.errors == 0
    finally:
        node.close()


def test_bad_input_is_counted_never_raised(monkeypatch, tmp_path, frames):
    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    node = FitterNode(params={"model": "facemesh"})
    node.setup()
    try:
        good = frames[0]
        empty = FaceLandmarks(stamp=5, points=np.zeros((0, 468, 3), np.float32), scores=np.zeros(0, np.float32),
                              rois=np.zeros((0, 5), np.float32), image_size=good.image_size, K=good.K)
        node.on_landmarks(empty)
        nan = FaceLandmarks(stamp=6, points=np.full((1, 468, 3), np.nan, np.float32), scores=good.scores,
                            rois=good.rois, image_size=good.image_size, K=good.K)
        node.on_landmarks(nan)
        zero = FaceLandmarks(stamp=7, points=good.points, scores=good.scores, rois=good.rois, image_size=[0, 0], K=good.K)
        node.on_landmarks(zero)
        few = FaceLandmarks(stamp=8, points=good.points[:, :20], scores=good.scores, rois=good.rois,
                            image_size=good.image_size, K=good.K)
        node.on_landmarks(few)
        c = node.counters
        assert c["no_face"] == 1 and c["bad_image_size"] == 1 and c["fit_refused"] == 2
        assert "fitted" not in c and node.errors == 0
        node.on_landmarks(good)  # and it still fits afterwards
        assert node.counters["fitted"] == 1
    finally:
        node.close()


def test_refine_appearance_takes_the_frames_and_fits_without_a_missing_one(monkeypatch, tmp_path, captured):
    """refine=appearance: the node keeps camera/image frames and refines each fit on its own
    frame (landmarks that come first wait for it); a fit whose frame never came is published
    unrefined and counted."""
    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    states = {}
    for refine in ("off", "appearance"):
        node = FitterNode(params={"refine": refine})
        node.setup()
        out = states[refine] = published_into(node.state_pub, [])
        try:
            for i, (frame, msg) in enumerate(captured):
                image = Image(stamp=msg.stamp, image=frame, K=msg.K)
                if refine == "appearance" and i == 7:             # the landmarks come before their frame:
                    node.on_landmarks(msg)
                    waited = len(out) == i                        # they wait for it
                    node.on_image(image)
                    assert waited and len(out) == i + 1
                    continue
                if refine == "appearance" and i != 5:             # frame 5's image is lost
                    node.on_image(image)
                node.on_landmarks(msg)
            if refine == "appearance":
                # frame 5's landmarks waited until frame 6 came, then went out unrefined
                assert node.counters["refine_without_frame"] == 1 and node.errors == 0
                assert node.fitter.config.refine == "appearance" and len(node.frames) == node.FRAMES_KEPT
                node.on_image(Image(stamp=1, image=captured[0][0], K=captured[0][1].K, halvings=1))
                assert node.counters["refine_bad_frame"] == 1
        finally:
            node.close()
    assert len(states["off"]) == len(states["appearance"]) == len(captured)
    moved = [np.abs(a.projected - b.projected).max() for a, b in zip(states["off"], states["appearance"])]
    assert 0.0 < max(moved[1:]) < 10.0                    # refined: moved, a little


def test_refine_pose_takes_the_frames_too(monkeypatch, tmp_path, captured):
    """refine=pose (the rigid pose from the pixels) subscribes to the frames as refine=appearance does."""
    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    node = FitterNode(params={"refine": "pose"})
    node.setup()
    out = published_into(node.state_pub, [])
    try:
        for frame, msg in captured:
            node.on_image(Image(stamp=msg.stamp, image=frame, K=msg.K))
            node.on_landmarks(msg)
        assert node.fitter.config.refine == "pose" and node.errors == 0 and len(out) == len(captured)
        assert "refine_without_frame" not in node.counters and node.fitter.refiner.frames == len(captured)
    finally:
        node.close()


def test_sfm_node_fits_the_68_point_mapping(monkeypatch, tmp_path, frames, data_dir):
    from facesculpt.nodes.fitter import load_model, save_model

    path = save_model(load_model("sfm"), tmp_path / "sfm.npz")
    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    node = FitterNode(params={"model": str(path), "projection": "orthographic", "model_period_s": 0.0})
    node.setup()
    states, models = published_into(node.state_pub, []), published_into(node.model_pub, [])
    try:
        for msg in frames:
            node.on_landmarks(msg)
        assert len(states) == len(frames)
        st = states[-1]
        assert st.vertices.shape == (3448, 3) and st.alpha.shape == (63,) and st.beta.shape == (6,)
        assert st.projection == "orthographic" and st.residual_px < 8
        assert (st.beta >= 0).all()
        # The accumulated identity changes the neutral: face/model follows it.
        assert models and models[-1].vertices.shape == (3448, 3)
        assert not np.allclose(models[-1].vertices, node.model.mean)
    finally:
        node.close()


@pytest.mark.slow
def test_a_learned_sparse_identity_is_republished_only_for_a_real_change(monkeypatch, tmp_path, frames, data_dir):
    """The SFM identity keeps moving a little with every frame. While it is learned (the first
    2 x neutral_frames frames) each 0.5 mm is republished; afterwards only a change past
    model_change_mm is."""
    from facesculpt.nodes.fitter import load_model, save_model

    path = save_model(load_model("sfm"), tmp_path / "sfm.npz")
    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    late = {}
    for change_mm in (0.5, 1000.0):
        node = FitterNode(params={"model": str(path), "projection": "orthographic", "model_period_s": 0.0,
                                  "neutral_frames": 3, "model_change_mm": change_mm})
        node.setup()
        published = []
        o_model = node.model_pub.publish
        node.model_pub.publish = lambda m: (published.append(node.fitter.frames_fitted), o_model(m))[1]
        try:
            for msg in frames:
                node.on_landmarks(msg)
        finally:
            node.close()
        assert any(1 <= n < 6 for n in published)  # learning
        late[change_mm] = [n for n in published if n >= 6]
    assert late[0.5] and not late[1000.0], late


def test_missing_model_stops_the_node_at_setup(monkeypatch, tmp_path):
    from facesculpt.runtime.parameters import ConfigurationError

    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    node = FitterNode(params={"model": str(tmp_path / "nope.npz")})
    try:
        with pytest.raises(ConfigurationError, match="fitter: cannot load model .*nope.npz"):
            node.setup()
    finally:
        node.close()


def test_real_process_publishes_state_and_latched_model(graph, frames):
    from facesculpt.runtime.node import Node
    from facesculpt.runtime.qos import EVERY_MESSAGE

    proc = graph.spawn("run", "fitter", "model=facemesh", "neutral_frames=3")
    client = Node(name="fitter_test_client")
    states: list[FaceState] = []
    models: list[FaceModel] = []
    pub = client.advertise("face/landmarks", FaceLandmarks)
    client.subscribe("face/state", FaceState, states.append, qos=EVERY_MESSAGE)
    client.subscribe("face/model", FaceModel, models.append, qos=EVERY_MESSAGE)
    client.start()
    try:
        deadline = time.monotonic() + 30
        k = 0
        while (len(states) < 5 or not models) and time.monotonic() < deadline:
            pub.publish(frames[k % len(frames)])
            k += 1
            client.spin_once(0.1)
        assert len(states) >= 5, f"no face/state from the fitter process: {client.diagnostics()}"
        assert models and models[-1].model_id == "facemesh" and models[-1].vertices.shape == (468, 3)
        stamps = {m.stamp for m in frames}
        assert all(s.stamp in stamps for s in states)
    finally:
        client.close()
        proc.terminate()
        assert proc.wait(10) == 0


@pytest.mark.slow
def test_expression_parameters_go_out_only_while_someone_subscribes(graph, frames):
    from facesculpt.msgs import Diagnostics, FaceExpression
    from facesculpt.nodes.fitter.expression import NAMES
    from facesculpt.runtime.node import Node
    from facesculpt.runtime.qos import EVERY_MESSAGE

    proc = graph.spawn("run", "fitter", "model=facemesh", "neutral_frames=3")
    client = Node(name="fitter_expression_client")
    states, stages = [], []
    pub = client.advertise("face/landmarks", FaceLandmarks)
    client.subscribe("face/state", FaceState, states.append, qos=EVERY_MESSAGE)
    client.subscribe("diagnostics", Diagnostics,
                     lambda m: stages.append(set(m.values.get("stages_ms", {}))) if m.node == "fitter" else None,
                     qos=EVERY_MESSAGE)
    client.start()

    def feed(until, seconds=30.0):
        deadline, k = time.monotonic() + seconds, 0
        while not until() and time.monotonic() < deadline:
            pub.publish(frames[k % len(frames)])
            k += 1
            client.spin_once(0.05)

    try:
        feed(lambda: len(states) >= 10 and len(stages) >= 2)
        assert len(states) >= 10 and any("fit" in s for s in stages)
        assert not any("expression" in s for s in stages)  # nobody asked for them: not computed
        expressions: list[FaceExpression] = []
        client.subscribe("face/expression", FaceExpression, expressions.append, qos=EVERY_MESSAGE)
        feed(lambda: len(expressions) >= 5)
        assert len(expressions) >= 5, "no face/expression once subscribed"
        e = expressions[-1]
        assert e.names == list(NAMES) and e.values.shape == (len(NAMES),) and np.isfinite(e.values).all()
        from facesculpt.nodes.fitter.expression_labels import LABELS

        # the expression recognised rides along (the first neutral_frames frames are its baseline)
        assert e.label in LABELS and 0.0 <= e.intensity <= 1.0 and e.phase in ("onset", "apex", "offset")
        assert e.label_scores.shape == (len(LABELS),)
        assert e.stamp in {m.stamp for m in frames}
    finally:
        client.close()
        proc.terminate()
        assert proc.wait(10) == 0
