"""Pose edits through the live graph (issue 18), messages and deformer: Deformation.pose and the
"pose" InputEvent on the wire; the deformer turning pose events into Deformation.pose without an
ARAP solve, in-process (real sockets) and as a real process; presets carrying a pose."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from test_deformer_node import DeformerClient, ev, face_model, face_state, make_node

from facesculpt.msgs import Deformation, InputEvent, decode, encode
from facesculpt.nodes.deformer.errors import DeformerError
from facesculpt.nodes.deformer.preset_format import find_preset, merge_presets, preset_pose, scale_preset


@pytest.fixture(scope="module")
def sfm(data_dir):
    from facesculpt.nodes.fitter import load_model

    return load_model("sfm")


def round_trip(msg):
    return decode([bytes(f) for f in encode(msg, "t")])[1]


# -- messages --------------------------------------------------------------------------------------
def test_deformation_and_input_event_carry_a_pose_and_stay_decodable_without_one():
    disp = np.zeros((4, 3), np.float32)
    plain = round_trip(Deformation(model_id="m", displacement=disp))
    assert plain.pose is None and plain.poses is None
    assert np.array_equal(plain.pose_of(0), np.zeros(6)) and plain.pose_of(0).dtype == np.float32

    one = round_trip(Deformation(model_id="m", displacement=disp, pose=np.array([10, -5, 0, 0, 0, 20], np.float32)))
    assert np.array_equal(one.pose_of(7), [10, -5, 0, 0, 0, 20])

    several = round_trip(Deformation(model_id="m", displacement=disp, face_id=3, pose=np.array([1, 0, 0, 0, 0, 0], np.float32),
                                     face_ids=np.array([3, 5], np.int32), displacements=np.zeros((2, 4, 3), np.float32),
                                     poses=np.array([[1, 0, 0, 0, 0, 0], [0, 2, 0, 0, 0, 0]], np.float32)))
    assert np.array_equal(several.pose_of(5), [0, 2, 0, 0, 0, 0]) and np.array_equal(several.pose_of(3), [1, 0, 0, 0, 0, 0])
    with pytest.raises(ValueError, match="poses"):  # poses must match face_ids
        encode(Deformation(model_id="m", displacement=disp, face_ids=np.array([3, 5], np.int32),
                           displacements=np.zeros((2, 4, 3), np.float32), poses=np.zeros((3, 6), np.float32)), "t")

    event = round_trip(InputEvent(kind="pose", pose=np.array([2, 0, 0, 0, 0, 0], np.float32), face=1))
    assert event.kind == "pose" and np.array_equal(event.pose, [2, 0, 0, 0, 0, 0]) and event.face == 1
    assert round_trip(InputEvent(kind="press", x=1.0, y=2.0)).pose is None
    assert round_trip(InputEvent(kind="command", command="reset_pose")).command == "reset_pose"


# -- the deformer ----------------------------------------------------------------------------------
def test_pose_events_publish_a_pose_without_solving_and_reset_clears_it(monkeypatch, tmp_path, sfm):
    n = make_node(monkeypatch, tmp_path)
    try:
        n.on_model(face_model(sfm))
        n.on_state(face_state(sfm))
        n.on_event(ev("move", landmark="nose_tip", vector=np.array([0.0, 0.0, 6.0], np.float32)))
        n.on_round()
        while n.settle_rounds:
            n.on_round()
        edited = n.last.displacement.copy()
        assert n.last.pose is None  # no pose edit: the message is as before
        solves = len(n.stage_times.get("solve", []))

        n.on_event(ev("pose", pose=np.array([2, 0, 0, 0, 0, 0], np.float32), stamp=200))
        n.on_event(ev("pose", argument="yaw=2,pitch=-3", stamp=201))
        n.on_event(ev("pose", pose=np.array([0, 0, 50, 0, 0, 0], np.float32), stamp=202))  # roll clamped at 45
        n.on_round()
        assert len(n.stage_times.get("solve", [])) == solves  # rigid: no ARAP solve
        assert n.last.stamp == 202
        assert np.allclose(n.last.pose, [4, -3, 45, 0, 0, 0])
        assert np.array_equal(n.last.displacement, edited)  # the shape edit is kept as it was

        n.on_event(ev("command", command="undo", stamp=203))  # undo drops the edit, not the pose
        n.on_round()
        assert np.allclose(n.last.pose, [4, -3, 45, 0, 0, 0]) and not np.any(n.last.displacement)
        n.on_event(ev("command", command="reset_pose", stamp=204))
        n.on_round()
        assert n.last.pose is None and n.last.stamp == 204
        n.on_event(ev("pose", argument="yaw=5", stamp=205))
        n.on_event(ev("command", command="reset", stamp=206))
        n.on_round()
        assert n.last.pose is None
        n.on_event(ev("pose", argument="sideways=5", stamp=207))  # bad input: counted, nothing changes
        n.on_event(ev("pose", stamp=208))
        n.on_round()
        assert n.counters["bad_input"] == 2 and n.last.pose is None
    finally:
        n.close()


def test_a_pose_event_turns_the_face_it_names_or_the_selected_one(monkeypatch, tmp_path, sfm):
    n = make_node(monkeypatch, tmp_path)
    try:
        model = face_model(sfm)
        model.face_ids = np.array([0, 4], np.int32)
        model.neutrals = np.stack([model.vertices, model.vertices])
        n.on_model(model)
        n.on_event(ev("pose", argument="yaw=10", face=4))
        n.on_round()
        assert list(n.last.face_ids) == [0, 4] and n.last.displacements.shape == (2, 3448, 3)
        assert np.allclose(n.last.pose_of(4), [10, 0, 0, 0, 0, 0]) and not np.any(n.last.pose_of(0))
        n.selected_face = 0  # as a press on face 0 makes it
        n.on_event(ev("pose", argument="pitch=3"))
        n.on_round()
        assert np.allclose(n.last.pose_of(0), [0, 3, 0, 0, 0, 0]) and np.allclose(n.last.pose_of(4), [10, 0, 0, 0, 0, 0])
    finally:
        n.close()


def test_presets_carry_a_pose_applied_on_load_and_saved_back(monkeypatch, tmp_path, sfm):
    doc = json.loads(find_preset("chin").read_text())
    doc["pose"] = {"yaw": 12, "z": 30}
    (tmp_path / "turned.json").write_text(json.dumps(doc))
    assert preset_pose(doc).as_list() == [12, 0, 0, 0, 0, 30]
    assert scale_preset(doc, 2.0)["pose"] == {"yaw": 24.0, "z": 60.0}
    assert scale_preset(doc, 3.0)["pose"]["yaw"] == 36.0 and scale_preset(dict(doc, strength=2), 3.0)["pose"]["yaw"] == 45.0
    assert merge_presets([doc, doc])["pose"] == {"yaw": 24.0, "z": 60.0}
    for bad, match in [({"yaw": 90}, "within ±45"), ({"turn": 3}, "only yaw"), ([10], "an object"), ({"yaw": "x"}, "an object")]:
        with pytest.raises(DeformerError, match=match):
            scale_preset(dict(doc, pose=bad))

    n = make_node(monkeypatch, tmp_path, preset="turned.json")  # the preset param: on the first model
    try:
        n.on_model(face_model(sfm))
        n.on_round()
        assert np.allclose(n.last.pose, [12, 0, 0, 0, 0, 30])
        n.on_event(ev("pose", argument="pitch=-4"))
        n.on_event(ev("command", command="save_preset", argument="saved.json"))
        n.on_event(ev("command", command="load_preset", argument="nose_longer"))  # no pose: the pose stays
        n.on_round()
        assert np.allclose(n.last.pose, [12, -4, 0, 0, 0, 30])
        saved = json.loads((tmp_path / "saved.json").read_text())
        assert saved["pose"] == {"yaw": 12.0, "pitch": -4.0, "z": 30.0}
        n.on_event(ev("command", command="reset_pose"))
        n.on_event(ev("command", command="load_preset", argument="saved.json"))
        n.on_round()
        assert np.allclose(n.last.pose, [12, -4, 0, 0, 0, 30])
    finally:
        n.close()


def test_deformer_process_publishes_pose_events(graph, sfm):
    """`facesculpt run deformer` in its own process: a pose event comes back as Deformation.pose."""
    proc = graph.spawn("run", "deformer", "round_s=0.02")
    client = DeformerClient("pose_test_client")
    got = client.got
    client.start()
    try:
        deadline = time.monotonic() + 30
        client.first_deformation(sfm, deadline)
        assert got and got[-1].pose is None
        for k in range(5):
            client.events.publish(ev("pose", pose=np.array([2, 0, -1, 0, 0, 0], np.float32), stamp=1000 + k))
        client.spin_until(lambda: got[-1].pose is not None and got[-1].pose[0] >= 10 - 1e-4, deadline)
        assert np.allclose(got[-1].pose, [10, 0, -5, 0, 0, 0]) and got[-1].stamp == 1004
        assert not np.any(got[-1].displacement)
    finally:
        client.node.close()
        proc.terminate()
        assert proc.wait(10) == 0
