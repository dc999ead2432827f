"""The deformer node: messages in, face/deformation out. In-process (callbacks and rounds
called directly, real sockets for publishing) and as a real process in a graph."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facesculpt.geometry import merge_deformation, project
from facesculpt.msgs import Deformation, FaceModel, FaceState, InputEvent
from facesculpt.nodes.deformer.edits import EditStack
from facesculpt.nodes.deformer.node import DeformerNode
from facesculpt.nodes.deformer.preset_format import find_preset

K = np.array([[900.0, 0.0, 320.0], [0.0, 900.0, 240.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def sfm(data_dir):
    from facesculpt.nodes.fitter import load_model

    return load_model("sfm")


def face_model(m, version=1):
    return FaceModel(
        stamp=1,
        model_id=m.model_id,
        vertices=m.mean.astype(np.float32),
        triangles=m.triangles.astype(np.int32),
        landmark_names=list(m.landmark_names),
        landmark_vertices=np.asarray(m.landmark_vertices, np.int32),
        units="mm",
        version=version,
    )


def face_state(m, yaw=30.0, stamp=2):
    R = np.diag([1.0, -1.0, -1.0]) @ Rotation.from_euler("y", yaw, degrees=True).as_matrix()
    s, t = 1.02, np.array([3.0, -5.0, 620.0])
    V = (s * m.mean.astype(np.float64) @ R.T + t).astype(np.float32)
    return FaceState(
        stamp=stamp, model_id=m.model_id, R=R, t=t, scale=s, K=K, alpha=np.zeros(0, np.float32),
        beta=np.zeros(0, np.float32), vertices=V, projected=project(V, K).astype(np.float32),
        image_size=[640, 480], projection="perspective",
    )


def ev(kind, **kw):
    return InputEvent(stamp=kw.pop("stamp", 100), kind=kind, **kw)


@pytest.fixture
def node(monkeypatch, tmp_path):
    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    n = DeformerNode(params={"preset_dir": str(tmp_path), "solve_share": 1.0})
    n.setup()
    n.running = True
    yield n
    n.close()


def screen(state, displacement, vertex):
    mesh = merge_deformation(state.vertices, state.R, state.scale, displacement)
    return mesh[vertex], project(mesh[[vertex]].astype(np.float64), state.K)[0]


def test_press_drags_coalesce_into_one_solve_that_follows_the_cursor(node, sfm):
    st = face_state(sfm)
    node.on_model(face_model(sfm))
    node.on_state(st)
    node.on_round()  # the new model: an empty deformation
    assert node.last is not None and np.all(node.last.displacement == 0)
    nose = sfm.landmark_index()["nose_tip"]
    x0, y0 = st.projected[nose]
    node.on_event(ev("press", x=float(x0), y=float(y0)))
    for k in range(1, 7):
        node.on_event(ev("drag", x=float(x0 + 5 * k), y=float(y0 - 2 * k), stamp=100 + k))
    solves_before = len(node.stage_times.get("solve", []))
    version_before = node.last.version
    node.on_round()
    assert len(node.stage_times["solve"]) == solves_before + 1  # six drags, one solve
    out = node.last
    assert out.version == version_before + 1 and out.stamp == 106
    assert out.model_id == sfm.model_id and out.displacement.shape == (3448, 3)
    (v,) = out.handles
    assert np.linalg.norm(sfm.mean[v] - sfm.mean[nose]) < 6.0  # picked next to the nose tip
    cam0, _ = screen(st, np.zeros((3448, 3)), v)
    cam1, px = screen(st, out.displacement, v)
    moved_px = px - project(cam0[None].astype(np.float64), K)[0]
    assert np.allclose(moved_px, [30.0, -12.0], atol=0.05)  # moved with the pointer
    assert abs(cam1[2] - cam0[2]) < 1e-2  # at its depth
    assert out.roi.size > 500 and v not in out.roi
    counters = node.diagnostics()["counters"]
    assert counters["press"] == 1 and counters["drag"] == 6


@pytest.mark.slow
def test_after_a_drag_idle_rounds_settle_the_edit_on_the_converged_solution(node, sfm):
    """A drag gets a few (accelerated) iterations per round; when the events stop, idle rounds go
    on solving until the mesh has converged, then stop: the last deformation is the ARAP solution
    of the edit, whatever path the drag took."""
    from facesculpt.nodes.deformer import ArapDeformer

    st = face_state(sfm)
    node.on_model(face_model(sfm))
    node.on_state(st)
    node.on_round()
    nose = sfm.landmark_index()["nose_tip"]
    x0, y0 = st.projected[nose]
    node.on_event(ev("press", x=float(x0), y=float(y0)))
    node.on_event(ev("drag", x=float(x0 + 40), y=float(y0 - 10), stamp=101))  # a fast flick: one round
    node.on_round()
    dragged = node.last.displacement.copy()
    rounds = 0
    while node.settle_rounds and rounds < 500:
        node.on_round()
        rounds += 1
    settled = node.last
    assert 0 < rounds < 100 and node.diagnostics()["counters"]["settle_rounds"] == rounds
    node.on_round()  # converged: idle rounds solve nothing more
    assert node.last is settled
    # the solver's constraints: the published handles plus the skin each grips (EditStack.constraints;
    # by default a handle grips nothing, as in the paper)
    static, constrained, roi, targets = node.editor.stack.constraints()
    assert set(settled.handles) <= set(constrained) and np.array_equal(settled.static, static)
    ref = ArapDeformer(sfm.mean, sfm.triangles, acceleration="none")
    ref.set_anchors(static=static, handles=constrained, roi=roi)
    rest = sfm.mean.astype(np.float64)
    ref.current = rest + settled.displacement
    converged = ref.solve(targets, iterations=1000) - rest
    diag = np.linalg.norm(np.ptp(rest, axis=0))
    assert np.abs(settled.displacement - converged).max() < 1e-3 * diag
    assert np.abs(dragged - converged).max() > np.abs(settled.displacement - converged).max()


def test_a_refined_neutral_keeps_the_edit_and_starts_from_it(node, sfm):
    """The fitter refines the neutral (same mesh, identity converging): the edit carries over by
    landmark and the solver starts from its last shape, so it settles in fewer rounds than the
    same edit solved from the rest mesh."""
    node.on_model(face_model(sfm))
    node.on_round()
    node.on_event(ev("press", landmark="nose_tip"))
    node.on_event(ev("move", vector=np.array([0.0, 2.0, 12.0], np.float32)))
    node.on_event(ev("release"))
    node.on_round()
    while node.settle_rounds:
        node.on_round()
    refined = face_model(sfm, version=2)
    refined.vertices = (refined.vertices * np.float32(1.02)).astype(np.float32)
    rounds = {}
    for start in ("warm", "cold"):
        if start == "cold":
            node.stack.deformer.reset()  # the same edit on the refined neutral, solved from rest
            node.dirty = True
        else:
            node.on_model(refined)
        node.on_round()
        rounds[start] = 1
        while node.settle_rounds:
            node.on_round()
            rounds[start] += 1
        nose = sfm.landmark_index()["nose_tip"]
        assert np.allclose(node.last.displacement[nose], [0.0, 2.0, 12.0], atol=1e-4)
    assert rounds["warm"] < rounds["cold"], rounds


def test_depth_move_axes_and_commands(node, sfm, tmp_path):
    st = face_state(sfm, yaw=0.0)
    node.on_model(face_model(sfm))
    node.on_state(st)
    lm = sfm.landmark_index()
    chin = lm["chin"]
    node.on_event(ev("press", landmark="chin"))
    node.on_event(ev("depth", depth=4.0))  # 4 mm toward the camera: at yaw 0, model +z
    node.on_round()
    d = node.last.displacement[chin]
    assert np.isclose(np.linalg.norm(d), 4.0, atol=1e-4) and d[2] > 3.9
    node.on_event(ev("move", vector=np.array([0.0, -3.0, 0.0], np.float32)))
    node.on_event(ev("release"))
    node.on_round()
    assert np.allclose(node.last.displacement[chin], d + [0, -3, 0], atol=1e-4)
    # joystick: the selected handle moves with the axes' velocity
    node.on_event(ev("axes", axes=np.array([0.0, -1.0, 0.0], np.float32)))
    node.on_round()
    time.sleep(0.1)
    node.on_event(ev("axes", axes=np.array([0.0, 0.0, 0.0], np.float32)))
    node.on_round()
    dy = node.last.displacement[chin][1] - (d[1] - 3.0)
    assert 0.5 * 0.1 * 40.0 < dy < 0.3 * 40.0  # ~40 mm/s for ~0.1 s, upward
    # a second edit, a preset, undo, reset
    node.on_event(ev("press", landmark="nose_tip"))
    node.on_event(ev("move", vector=np.array([0.0, 0.0, 10.0], np.float32)))
    node.on_event(ev("command", command="save_preset", argument="two.json"))
    node.on_round()
    saved = node.last.displacement.copy()
    doc = json.loads((tmp_path / "two.json").read_text())
    assert [h["landmark"] for e in doc["edits"] for h in e["handles"]] == ["chin", "nose_tip"]
    # select_edit: a move with no pointer now acts on edit 0 (the chin), not on the nose just pressed
    node.on_event(ev("release"))
    node.on_event(ev("command", command="select_edit", argument="0"))
    node.on_event(ev("move", vector=np.array([0.0, -2.0, 0.0], np.float32)))
    node.on_round()
    assert np.isclose(node.last.displacement[chin][1] - saved[chin][1], -2.0, atol=1e-4)
    assert np.isclose(node.last.displacement[lm["nose_tip"]][2], saved[lm["nose_tip"]][2], atol=1e-4)
    bad_before = node.counters.get("bad_input", 0)
    node.on_event(ev("command", command="select_edit", argument="7"))
    node.on_round()
    assert node.counters["bad_input"] == bad_before + 1 and "select_edit needs an edit number" in node.last_diagnostic
    node.on_event(ev("command", command="undo"))
    node.on_round()
    assert abs(node.last.displacement[lm["nose_tip"]][2]) < 1.0  # the nose edit is gone
    assert list(node.last.handles) == [chin]
    node.on_event(ev("command", command="reset"))
    node.on_round()
    assert np.all(node.last.displacement == 0) and node.last.handles.size == 0
    node.on_event(ev("command", command="load_preset", argument=str(tmp_path / "two.json")))
    node.on_round()
    assert np.allclose(node.last.displacement[[chin, lm["nose_tip"]]], saved[[chin, lm["nose_tip"]]], atol=1e-5)


def test_bad_input_is_counted_and_last_good_deformation_stays(node, sfm, tmp_path):
    st = face_state(sfm)
    node.on_model(face_model(sfm))
    node.on_event(ev("press", landmark="nose_tip"))  # no state needed for a landmark press
    node.on_event(ev("move", vector=np.array([0.0, 0.0, 5.0], np.float32)))
    node.on_round()
    while node.settle_rounds:  # let the edit converge: idle rounds then solve nothing more
        node.on_round()
    good = node.last
    node.on_event(ev("drag", x=100.0, y=100.0, handle=3))  # no press for pointer 3
    node.on_event(ev("press", x=1.0, y=1.0))  # no face/state yet
    node.on_round()
    node.on_state(st)
    node.on_event(ev("press", x=1.0, y=1.0))  # background: a miss
    node.on_event(ev("press", landmark="third_ear"))
    node.on_event(ev("move", vector=np.array([np.nan, 0.0, 0.0], np.float32)))
    node.on_event(ev("depth", depth=float("inf")))
    node.on_event(ev("command", command="load_preset", argument="missing.json"))
    node.on_round()
    assert node.last is good  # nothing valid happened: no new solve, the last deformation stays
    c = node.diagnostics()["counters"]
    assert c["bad_input"] == 6 and c["pick_miss"] == 1
    # a preset whose ROI holds no free vertex: the solve is rejected and rolled back
    doc = {"format": "facesculpt-deformer-preset", "version": 1, "static": [],
           "edits": [{"handles": [{"landmark": "chin", "offset": [0, 0, 3]}], "roi": {"radius": 1e-4}}]}
    (tmp_path / "empty_roi.json").write_text(json.dumps(doc))
    node.on_event(ev("command", command="load_preset", argument="empty_roi.json"))
    node.on_round()
    assert node.last is good
    diag = node.diagnostics()
    assert diag["counters"]["solve_rejected"] == 1 and "empty" in diag["last_diagnostic"]
    node.on_event(ev("move", landmark="nose_tip", vector=np.array([0.0, 1.0, 0.0], np.float32)))
    node.on_round()  # the rolled-back edits still work
    assert np.allclose(node.last.displacement[sfm.landmark_index()["nose_tip"]], [0, 1, 5], atol=1e-5)
    assert node.errors == 0  # nothing escaped into the base class's error handler


class DeformerClient:
    """A node facing a `facesculpt run deformer` process: publishers of face/model (latched),
    face/state and input/events, and every face/deformation in ``got``. Subscribe more on
    ``node`` before :meth:`start`."""

    def __init__(self, name: str):
        from facesculpt.runtime.node import Node
        from facesculpt.runtime.qos import EVERY_MESSAGE, LATCHED

        self.node = Node(name=name)
        self.got: list[Deformation] = []
        self.model = self.node.advertise("face/model", FaceModel, qos=LATCHED)
        self.state = self.node.advertise("face/state", FaceState)
        self.events = self.node.advertise("input/events", InputEvent)
        self.node.subscribe("face/deformation", Deformation, self.got.append, qos=EVERY_MESSAGE)

    def start(self) -> None:
        self.node.start()

    def first_deformation(self, model, deadline: float) -> None:
        """Publish ``model``'s face/model, then its face/state until the deformer answers (it
        answers the model with an empty edit) or the monotonic ``deadline`` passes."""
        self.model.publish(face_model(model))
        while not self.got and time.monotonic() < deadline:
            self.state.publish(face_state(model))
            self.node.spin_once(0.2)

    def spin_until(self, done, deadline: float) -> None:
        while time.monotonic() < deadline and not done():
            self.node.spin_once(0.1)


@pytest.mark.slow
def test_real_process_receives_every_event_and_publishes(graph, sfm):
    """`facesculpt run deformer` in its own process: latched model, state, 40 queued moves."""
    from facesculpt.msgs import Diagnostics
    from facesculpt.runtime.qos import EVERY_MESSAGE

    proc = graph.spawn("run", "deformer", "round_s=0.02")
    client = DeformerClient("deformer_test_client")
    got = client.got
    diags = []
    client.node.subscribe("diagnostics", Diagnostics, lambda m: diags.append((m.node, m.values)), qos=EVERY_MESSAGE)
    client.start()
    try:
        deadline = time.monotonic() + 30
        client.first_deformation(sfm, deadline)
        assert got, f"no face/deformation from the deformer process: {client.node.diagnostics()} {[d for d in diags if d[0]=='deformer'][-1:]}"
        client.events.publish(ev("press", landmark="nose_tip"))
        for k in range(40):
            client.events.publish(ev("move", vector=np.array([0.0, 0.0, 0.25], np.float32), stamp=1000 + k))
        nose = sfm.landmark_index()["nose_tip"]
        client.spin_until(lambda: got[-1].displacement[nose][2] >= 10.0 - 1e-4, deadline)
        assert np.isclose(got[-1].displacement[nose][2], 10.0, atol=1e-4)  # no move lost
        assert got[-1].stamp == 1039
        assert len(got) < 1 + 41  # moves were coalesced into fewer solves
    finally:
        client.node.close()
        proc.terminate()
        assert proc.wait(10) == 0


def make_node(monkeypatch, tmp_path, **params):
    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    n = DeformerNode(params={"preset_dir": str(tmp_path), "solve_share": 1.0, **params})
    n.setup()
    n.running = True
    return n


def test_rounds_rest_after_a_solve_so_solving_keeps_to_its_share_of_a_core(monkeypatch, tmp_path, sfm):
    """solve_share 0.25: after a solve of t s the rounds wait 3 t (at most MAX_REST_S); an event
    sent meanwhile waits in the queue and is solved by the first round after the rest."""
    from facesculpt.nodes.deformer.node import MAX_REST_S

    n = make_node(monkeypatch, tmp_path, solve_share=0.25)
    try:
        nose = sfm.landmark_index()["nose_tip"]
        n.on_model(face_model(sfm))
        n.on_state(face_state(sfm))
        n.on_event(ev("move", landmark="nose_tip", vector=np.array([0.0, 0.0, 4.0], np.float32)))
        t0 = time.monotonic()
        n.on_round()
        spent = time.monotonic() - t0
        solved = n.last
        rest = n.rest_until - time.monotonic()
        assert solved is not None and 0 < rest <= min(MAX_REST_S, 3 * spent)
        n.on_event(ev("move", landmark="nose_tip", vector=np.array([0.0, 0.0, 4.0], np.float32), stamp=101))
        n.on_round()  # resting: the move waits
        assert n.last is solved and len(n.pending) == 1
        time.sleep(max(0.0, n.rest_until - time.monotonic()) + 0.001)
        n.on_round()
        assert n.last is not solved and not n.pending
        assert np.allclose(n.last.displacement[nose], [0.0, 0.0, 8.0], atol=1e-4)
    finally:
        n.close()
    n = make_node(monkeypatch, tmp_path)  # solve_share 1: no rest
    try:
        n.on_model(face_model(sfm))
        n.on_event(ev("move", landmark="nose_tip", vector=np.array([0.0, 0.0, 4.0], np.float32)))
        n.on_round()
        assert n.last is not None and n.rest_until <= time.monotonic()
    finally:
        n.close()


def test_preset_param_applies_on_the_first_model_and_follows_model_changes(monkeypatch, tmp_path, sfm):
    """`deformer.preset=chin strength=2`: the chin edit (offsets doubled) is published as soon
    as a face/model arrives, stays through a refined neutral, and a user's change to it is kept."""
    n = make_node(monkeypatch, tmp_path, preset="chin", strength=2.0)
    try:
        chin = sfm.landmark_index()["chin"]
        offset = 2.0 * np.array(json.loads(find_preset("chin").read_text())["edits"][0]["handles"][0]["offset"])
        n.on_round()
        assert n.last is None  # nothing before a model
        n.on_model(face_model(sfm))
        n.on_round()
        # the face mesh's chin patch placed on this model: offsets scaled to its face size and turned to its axes
        placed = n.last.displacement[chin].copy()
        assert np.linalg.norm(placed - offset) < 0.1 * np.linalg.norm(offset) and chin in list(n.last.handles)
        assert n.diagnostics()["counters"]["preset_loaded"] == 1
        # a refined neutral of the same mesh (the fitter learning the person): the preset again
        refined = face_model(sfm, version=2)
        refined.vertices = sfm.instance(np.linspace(-1, 1, sfm.num_shape)).astype(np.float32)
        n.on_model(refined)
        n.on_round()
        placed = n.last.displacement[chin].copy()   # this neutral's face size
        assert np.linalg.norm(placed - offset) < 0.1 * np.linalg.norm(offset) and chin in list(n.last.handles)
        # the user moves the chin: a later neutral carries the user's edit, not the preset's
        n.on_event(ev("move", landmark="chin", vector=np.array([0.0, 1.0, 0.0], np.float32)))
        n.on_round()
        n.on_model(face_model(sfm, version=3))
        n.on_round()
        assert np.allclose(n.last.displacement[chin], placed + [0, 1, 0], atol=1e-4)
        assert n.errors == 0 and "preset_rejected" not in n.counters
    finally:
        n.close()


def test_a_missing_or_malformed_preset_param_stops_the_node_at_start(monkeypatch, tmp_path, graph):
    from facesculpt.runtime.parameters import ConfigurationError

    (tmp_path / "broken.json").write_text("{not json")
    doc = json.loads(find_preset("nose_longer").read_text())
    doc["strength"] = 4
    (tmp_path / "too_strong.json").write_text(json.dumps(doc))
    for value, message in [("no_such_preset", "'no_such_preset' not found .*shipped: cheeks, chin, nose_longer"),
                           ("broken.json", "cannot read preset .*broken.json"),
                           ("too_strong.json", "preset strength 4 is outside 0..3")]:
        monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
        n = DeformerNode(params={"preset_dir": str(tmp_path), "preset": value})
        try:
            with pytest.raises(ConfigurationError, match=message):
                n.setup()
        finally:
            n.close()
    # as a process: exit status 2 (not respawned by a launcher) and one line naming the preset
    r = graph.run("run", "deformer", f"preset_dir={tmp_path}", "preset=broken.json", timeout=60)
    assert r.returncode == 2, r.stderr
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "broken.json" in lines[0] and "Traceback" not in r.stderr, r.stderr


def test_save_preset_logs_its_absolute_path_and_strength_scales_loads(monkeypatch, tmp_path, sfm, caplog):
    import logging

    n = make_node(monkeypatch, tmp_path)
    weak = make_node(monkeypatch, tmp_path, strength=0.5)
    try:
        nose = sfm.landmark_index()["nose_tip"]
        n.on_model(face_model(sfm))
        n.on_event(ev("move", landmark="nose_tip", vector=np.array([0.0, -2.0, 8.0], np.float32)))
        with caplog.at_level(logging.INFO, logger="facesculpt"):
            n.on_event(ev("command", command="save_preset", argument="mine.json"))
            n.on_round()
        path = (tmp_path / "mine.json").resolve()
        assert path.is_file()
        assert f"saved the edits as preset {path}" in [r.getMessage() for r in caplog.records]
        assert n.diagnostics()["last_saved_preset"] == str(path)
        weak.on_model(face_model(sfm))
        weak.on_event(ev("command", command="load_preset", argument="mine.json"))
        weak.on_event(ev("command", command="load_preset", argument="nose_longer"))  # a shipped name
        weak.on_round()
        # the shipped preset was made on the face mesh: its offset reaches this model through its landmarks
        full = EditStack(sfm.mean, sfm.triangles, list(sfm.landmark_names), sfm.landmark_vertices)
        full.apply_preset(json.loads(find_preset("nose_longer").read_text()))
        assert np.allclose(weak.last.displacement[nose], 0.5 * full.edits[0].offsets[nose], atol=1e-4)
        weak.on_event(ev("command", command="load_preset", argument=str(path)))
        weak.on_round()
        assert np.allclose(weak.last.displacement[nose], [0.0, -1.0, 4.0], atol=1e-4)
        assert weak.diagnostics()["last_saved_preset"] == ""
    finally:
        n.close()
        weak.close()
