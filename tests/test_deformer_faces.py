"""The deformer with several faces: each face its own edits on its own neutral; a press goes to
the face under the pointer, an event can name a face, a preset goes to every face; one
Deformation carries every face's displacement."""

from __future__ import annotations

import numpy as np
import pytest
from test_deformer_node import K, ev, face_model, face_state

from facesculpt.geometry import project
from facesculpt.nodes.deformer.node import DeformerNode


def shifted_state(m, face_id: int, dx_mm: float):
    st = face_state(m, yaw=0.0)
    st.t = st.t + np.array([dx_mm, 0.0, 0.0])
    st.vertices = (st.vertices + np.array([dx_mm, 0.0, 0.0], np.float32)).astype(np.float32)
    st.projected = project(st.vertices, K).astype(np.float32)
    st.face_id = face_id
    st.faces = 2
    return st


@pytest.fixture
def two_faces(monkeypatch, tmp_path, data_dir):
    from facesculpt.nodes.fitter import load_model

    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    m = load_model("sfm")
    node = DeformerNode(params={"round_s": 1.0, "solve_share": 1.0})
    node.setup()
    node.running = True
    model = face_model(m)
    wider = (m.mean * np.float32(1.08)).astype(np.float32)  # the second person's own neutral
    model.face_ids = np.array([0, 3], np.int32)
    model.neutrals = np.stack([m.mean.astype(np.float32), wider])
    node.on_model(model)
    left, right = shifted_state(m, 0, -120.0), shifted_state(m, 3, 120.0)
    node.on_state(left)
    node.on_state(right)
    node.on_round()
    yield node, m, left, right
    node.close()


def moved(node, face_id):
    d = node.last.displacement_of(face_id)
    return float(np.linalg.norm(d, axis=1).max())


def test_a_press_edits_the_face_under_the_pointer_only(two_faces):
    node, m, left, right = two_faces
    assert sorted(node.editors) == [0, 3]
    nose = m.landmark_index()["nose_tip"]
    x, y = right.projected[nose]
    node.on_event(ev("press", x=float(x), y=float(y)))
    node.on_event(ev("drag", x=float(x + 20), y=float(y)))
    node.on_event(ev("release"))
    node.on_round()
    out = node.last
    assert out.face_ids.tolist() == [0, 3] and out.displacements.shape == (2, m.mean.shape[0], 3)
    assert moved(node, 3) > 5.0 and moved(node, 0) == 0.0
    assert out.face_id == 3 and out.handles.size == 1  # the overlay shows the face being edited
    # each face is solved on its own neutral: the handle sits on the wider face's nose
    assert node.editors[3].stack.rest[nose][0] == pytest.approx(m.mean[nose][0] * 1.08, abs=1e-3)


def test_events_can_name_a_face_and_presets_go_to_every_face(two_faces):
    node, m, left, right = two_faces
    node.on_event(ev("press", landmark="nose_tip", face=0))
    node.on_event(ev("move", vector=np.array([0, 0, 10.0], np.float32), face=0))
    node.on_round()
    assert moved(node, 0) > 9.0 and moved(node, 3) == 0.0
    node.on_event(ev("command", command="load_preset", argument="chin"))
    node.on_round()
    assert moved(node, 0) > 3.0 and moved(node, 3) > 3.0
    chin = m.landmark_index()["chin"] if "chin" in m.landmark_index() else None
    if chin is not None:
        assert np.allclose(node.last.displacement_of(0)[chin], node.last.displacement_of(3)[chin], atol=3.0)
    node.on_event(ev("command", command="reset", face=3))
    node.on_round()
    assert moved(node, 3) == 0.0 and moved(node, 0) > 3.0
    before = node.counters.get("event_for_unknown_face", 0)
    node.on_event(ev("command", command="reset", face=9))
    node.on_round()
    assert node.counters["event_for_unknown_face"] == before + 1 and moved(node, 0) > 3.0


def test_a_press_between_the_faces_is_a_miss(two_faces):
    node, m, left, right = two_faces
    node.on_event(ev("press", x=320.0, y=5.0))
    node.on_round()
    assert node.counters["pick_miss"] == 1 and "on no face" in node.last_diagnostic
