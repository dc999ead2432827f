"""The scripted-gesture node in a graph: against the deformer fed a synthetic fitted face (the
Surrey Face Model's mean under a known pose), against the whole graph on a recorded bag of a
real video, and with bad input."""

from __future__ import annotations

import time

import numpy as np
import pytest
from conftest import REPO_ROOT
from scipy.spatial.transform import Rotation

from facesculpt.geometry import project
from facesculpt.msgs import Deformation, Diagnostics, FaceModel, FaceState, InputEvent
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE, LATCHED

GESTURES = REPO_ROOT / "examples" / "gestures"
K = np.array([[900.0, 0.0, 320.0], [0.0, 900.0, 240.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def sfm(data_dir):
    from facesculpt.nodes.fitter import load_model

    return load_model("sfm")


def sfm_model_msg(m) -> FaceModel:
    return FaceModel(stamp=1, model_id=m.model_id, vertices=m.mean.astype(np.float32),
                     triangles=m.triangles.astype(np.int32), landmark_names=list(m.landmark_names),
                     landmark_vertices=np.asarray(m.landmark_vertices, np.int32), units="mm", version=1)


def sfm_state_msg(m, stamp: int, yaw_deg: float = 15.0) -> FaceState:
    """The mean face 600 mm in front of the camera, turned by ``yaw_deg`` (x_cam = s R x + t)."""
    R = np.diag([1.0, -1.0, -1.0]) @ Rotation.from_euler("y", yaw_deg, degrees=True).as_matrix()
    s, t = 1.0, np.array([0.0, 0.0, 600.0])
    V = (s * m.mean.astype(np.float64) @ R.T + t).astype(np.float32)
    return FaceState(stamp=stamp, model_id=m.model_id, R=R, t=t, scale=s, K=K, alpha=np.zeros(0, np.float32),
                     beta=np.zeros(0, np.float32), vertices=V, projected=project(V, K).astype(np.float32),
                     image_size=[640, 480], projection="perspective")


class FakeFitter:
    """The test's stand-in for landmarks + fitter: a latched face/model and face/state at 10 Hz;
    collects face/deformation and every node's diagnostics."""

    def __init__(self, graph, m):
        self.graph, self.m = graph, m
        self.node = Node(name="script_test_fitter")
        self.model_pub = self.node.advertise("face/model", FaceModel, qos=LATCHED)
        self.state_pub = self.node.advertise("face/state", FaceState)
        self.deformations: list[Deformation] = []
        self.diag: dict[str, dict] = {}
        self.node.subscribe("face/deformation", Deformation, self.deformations.append, qos=EVERY_MESSAGE)
        self.node.subscribe("diagnostics", Diagnostics, lambda d: self.diag.__setitem__(d.node, d.values),
                            qos=EVERY_MESSAGE)
        self.publishing = False
        self.node.timer(0.1, self.tick)
        self.frame = 0
        graph.node(self.node)

    def start_face(self):
        self.model_pub.publish(sfm_model_msg(self.m))
        self.publishing = True

    def tick(self):
        if self.publishing:
            self.frame += 1
            self.state_pub.publish(sfm_state_msg(self.m, stamp=time.time_ns()))

    def spin_until(self, predicate, timeout):
        return self.graph.spin_until(self.node, predicate, timeout)


@pytest.mark.slow
def test_nose_pull_script_moves_the_nose_tip_by_the_scripted_mm(graph, sfm):
    """examples/gestures/nose_pull.yaml through `facesculpt run script` and `facesculpt run deformer`:
    the script waits for the face, then the nose-tip vertex ends exactly 12 mm out of the face."""
    deformer = graph.spawn("run", "deformer", "round_s=0.02")
    script = graph.spawn("run", "script", f"script={GESTURES / 'nose_pull.yaml'}", "exit_when_done=true")
    fitter = FakeFitter(graph, sfm)
    # no face yet: the script must not start (a press now would reach a deformer with no model)
    assert fitter.spin_until(lambda: "waiting for a fitted face" in fitter.diag.get("script", {}).get("status", ""), 20)
    fitter.start_face()
    nose = sfm.landmark_index()["nose_tip"]
    assert fitter.spin_until(lambda: script.poll() is not None, 20), "the script did not finish"
    assert script.returncode == 0
    assert fitter.spin_until(lambda: fitter.deformations and np.linalg.norm(
        fitter.deformations[-1].displacement[nose] - [0, 0, 12]) < 1e-3, 5)
    last = fitter.deformations[-1]
    assert list(last.handles) == [nose] and last.model_id == sfm.model_id
    d = np.linalg.norm(last.displacement, axis=1)
    chin = sfm.landmark_index()["chin"]
    assert d[chin] < 0.5 and d.max() == pytest.approx(12.0, abs=1e-3)  # a local pull, nose tip the most
    # in camera space the tip came 12 mm toward the camera along the face's forward direction
    state = sfm_state_msg(sfm, 0)
    moved = state.scale * state.R @ last.displacement[nose].astype(np.float64)
    assert np.allclose(moved, state.R @ [0, 0, 12.0], atol=1e-3) and moved[2] < -11.0
    assert fitter.spin_until(lambda: "counters" in fitter.diag.get("deformer", {}), 5)
    counters = fitter.diag["deformer"]["counters"]
    assert counters.get("press") == 1 and "events_without_model" not in counters and "bad_input" not in counters
    assert deformer.poll() is None


@pytest.mark.slow
def test_bad_input_one_sentence_each_and_the_graph_keeps_running(graph, sfm, tmp_path):
    deformer = graph.spawn("run", "deformer", "round_s=0.02")
    fitter = FakeFitter(graph, sfm)
    fitter.start_face()
    # a script with a syntax error: the node stops at once with the file, line and problem
    bad = tmp_path / "bad.yaml"
    bad.write_text("steps:\n  - press: nose_tip\n  - drag: {mm: [0, 0, 5], duration_s: 1\n  - release\n")
    out = graph.run("run", "script", f"script={bad}")
    assert out.returncode == 1 and "Traceback" not in out.stderr
    assert out.stderr.strip().splitlines()[-1] == (
        f"facesculpt: {bad} line 3, column 11: not valid YAML (while parsing a flow mapping: "
        "expected ',' or '}', but got '<stream end>' at line 5, column 1)")
    # an unknown landmark: one sentence, the script stops, its node stays up
    unknown = tmp_path / "unknown.yaml"
    unknown.write_text("steps:\n  - press: nose_tip\n  - release\n  - press: third_ear\n")
    err = tmp_path / "script.err"
    with open(err, "w") as f:
        script = graph.spawn("run", "script", f"script={unknown}", stderr=f)
    # a joystick whose device is missing keeps retrying
    joystick = graph.spawn("run", "joystick", "port=/dev/no-such-joystick")
    assert fitter.spin_until(lambda: fitter.diag.get("script", {}).get("status", "").startswith("stopped")
                             and fitter.diag.get("joystick", {}).get("counters", {}).get("open_failures"), 20)
    sentence = f"{unknown} line 4: 'third_ear' is not a landmark of model {sfm.model_id} (known: chin, forehead,"
    assert fitter.diag["script"]["last_diagnostic"].startswith(sentence)
    assert err.read_text().count(sentence) == 1 and "Traceback" not in err.read_text()
    assert fitter.diag["script"]["counters"].get("events", 0) == 0  # checked before pressing anything
    assert fitter.diag["joystick"]["last_diagnostic"].startswith(
        "cannot open serial port /dev/no-such-joystick: no such device")
    # the graph goes on: every node is up, and the deformer still takes events
    assert script.poll() is None and joystick.poll() is None and deformer.poll() is None
    events = fitter.node.advertise("input/events", InputEvent)
    assert events.wait_for_subscribers(1, 10)  # the deformer
    nose = sfm.landmark_index()["nose_tip"]
    events.publish(InputEvent(stamp=time.time_ns(), kind="move", landmark="nose_tip", handle=5,
                              vector=np.array([0, 3.0, 0], np.float32)))
    assert fitter.spin_until(lambda: fitter.deformations and np.allclose(
        fitter.deformations[-1].displacement[nose], [0, 3, 0], atol=1e-4), 10)


def _record_bag(video, path, frames: int) -> None:
    """A bag of `camera/image` from a real video, as `facesculpt bag record` writes it."""
    import cv2

    from facesculpt.msgs import Image
    from facesculpt.nodes.camera.intrinsics import intrinsics_from_fov
    from facesculpt.runtime.bag import BagWriter

    cap = cv2.VideoCapture(str(video))
    with BagWriter(path, compression="jpeg") as bag:
        for i in range(frames):
            ok, frame = cap.read()
            if not ok:
                break
            h, w = frame.shape[:2]
            stamp = 1_000_000_000 + i * 33_333_333
            msg = Image(stamp=stamp, seq=i + 1, image=frame, K=intrinsics_from_fov(w, h, 60.0))
            bag.write(stamp, "camera/image", msg.to_frames())
    cap.release()


DRAG_WINDOW_NS = 3_000_000_000  # the drag's 0.5 s and up to 2.5 s of the graph's lag on a busy machine


def _face_px(state: FaceState) -> float:
    """The size of a fitted face in its frame: RMS distance of its projected vertices from their mean, px."""
    p = state.projected.astype(np.float64)
    return float(np.sqrt(((p - p.mean(axis=0)) ** 2).sum(axis=1).mean()))


def _face_sizes_before(states: dict[int, FaceState], end: int) -> list[float]:
    """The fitted face's sizes (px) in the DRAG_WINDOW_NS before ``end``; the last one before it if none."""
    window = [s for s in states if end - DRAG_WINDOW_NS <= s <= end] or [max(s for s in states if s <= end)]
    return [_face_px(states[s]) for s in window]


@pytest.mark.slow
def test_whole_graph_on_a_recorded_bag_pulls_the_nose(graph, data_dir, models_dir, tmp_path):
    """camera (a bag of d3.mp4) -> landmarks -> fitter -> deformer -> renderer, with the script
    dragging the nose tip 24 px to the right. In the output, per rendered frame: the nose-tip
    vertex as the renderer draws it (face/state merged with face/deformation) is 24 px (+-20 %)
    to the right of the fitted one, and in render/image the camera frame's nose patch has moved
    right by what the mesh under it moved (the tip the most, its neighbours less: ARAP around a
    one-vertex handle)."""
    import cv2

    from facesculpt.geometry import merge_deformation
    from facesculpt.msgs import Image

    bag = tmp_path / "d3.bag"
    _record_bag(data_dir / "video" / "d3.mp4", bag, 120)
    scripted = 24.0
    gesture = tmp_path / "nose_right.yaml"
    gesture.write_text(f"steps:\n  - press: nose_tip\n  - drag: {{px: [{scripted}, 0], duration_s: 0.5}}\n"
                       "  - release\n")
    graph.spawn("run", "camera", f"source=bag:{bag}", "loop=true", "fps=10")
    graph.spawn("run", "landmarks")
    graph.spawn("run", "fitter")
    graph.spawn("run", "deformer")
    graph.spawn("run", "renderer", "publish=true", "pairing=sync")
    script = graph.spawn("run", "script", f"script={gesture}", "start_delay_s=1.0", "exit_when_done=true")

    frames: dict[int, Image] = {}
    renders: dict[int, Image] = {}
    states: dict[int, FaceState] = {}
    model: list[FaceModel] = []
    deformations: list[Deformation] = []
    watcher = Node(name="script_test_watcher")
    watcher.subscribe("camera/image", Image, lambda m: frames.__setitem__(m.stamp, m), qos=EVERY_MESSAGE)
    watcher.subscribe("render/image", Image, lambda m: renders.__setitem__(m.stamp, m), qos=EVERY_MESSAGE)
    watcher.subscribe("face/state", FaceState, lambda m: states.__setitem__(m.stamp, m), qos=EVERY_MESSAGE)
    watcher.subscribe("face/model", FaceModel, model.append)
    watcher.subscribe("face/deformation", Deformation, deformations.append, qos=EVERY_MESSAGE)
    graph.node(watcher)
    assert graph.spin_until(watcher, lambda: script.poll() is not None, 90), "the script did not play"
    assert script.returncode == 0
    after = time.time_ns() + 300_000_000  # frames captured well after the last drag was solved
    assert graph.spin_until(watcher, lambda: sum(s > after and s in frames and s in states for s in renders) >= 5, 60)
    nose = int(model[-1].landmark_vertices[list(model[-1].landmark_names).index("nose_tip")])
    displacement = deformations[-1].displacement
    # The drag is turned into millimetres on the face as the deformer last saw it, event by event;
    # d3 leans in and out and the bag loops (a jump in size), so a later frame shows those
    # millimetres as more or fewer pixels. Which states the deformer used is not published: the
    # face's size is bounded by the states of the drag's seconds (its 0.5 s and the graph's lag).
    sizes = _face_sizes_before(states, deformations[-1].stamp)
    r = 10  # nose patch half-size, px
    checked = 0
    for stamp in sorted(s for s in renders if s > after and s in frames and s in states):
        st = states[stamp]
        drawn = project(merge_deformation(st.vertices.astype(np.float64), st.R, st.scale, displacement), st.K,
                        st.projection)
        mesh_shift = drawn - st.projected
        tip = mesh_shift[nose]
        low, high = (scripted * _face_px(st) / size for size in (max(sizes), min(sizes)))
        assert 0.8 * low <= tip[0] <= 1.2 * high and abs(tip[1]) <= 0.2 * low, f"tip moved {tip}, {low}..{high}"
        x, y = (int(round(c)) for c in st.projected[nose])
        in_patch = np.all(np.abs(st.projected - st.projected[nose]) <= r, axis=1)
        patch = frames[stamp].image[y - r:y + r + 1, x - r:x + r + 1]
        window = renders[stamp].image[y - r - 10:y + r + 11, x - r - 10:x + r + 41]  # up to 40 px right
        score = cv2.matchTemplate(window, patch, cv2.TM_CCOEFF_NORMED)
        _, best, _, (bx, by) = cv2.minMaxLoc(score)
        dx, dy = bx - 10, by - 10
        assert best > 0.7, f"the nose patch is not in the output (match {best:.2f})"
        # The texture moves with the mesh. One shift for the whole patch (template matching) falls
        # short of the vertices' mean: the nose tip moves most, and the match weighs the patch's
        # strongest edges (nostrils, the nose's side), where the converged ARAP shape moves less.
        assert 0.6 * mesh_shift[in_patch, 0].mean() <= dx <= 1.2 * tip[0] and abs(dy) <= 3, (dx, dy, tip)
        # No background distortion: outside the original and the deformed face regions (their
        # outlines' hulls, which include the closed eyes and mouth), dilated by 2 px, nothing changed.
        face = np.zeros(frames[stamp].image.shape[:2], np.uint8)
        for pts in (st.projected, drawn):
            cv2.fillConvexPoly(face, cv2.convexHull(np.round(pts).astype(np.int32)), 1)
        outside = cv2.dilate(face, np.ones((5, 5), np.uint8)) == 0
        assert np.array_equal(renders[stamp].image[outside], frames[stamp].image[outside])
        assert (renders[stamp].image[~outside] != frames[stamp].image[~outside]).any()
        checked += 1
    assert checked >= 5


@pytest.mark.slow
def test_loop_start_delay_and_a_failed_batch_run(graph, tmp_path):
    """In-process: no face or deformer to wait for; the delay holds the first event back; each
    pass plays every event; a script that fails while playing ends a batch run with status 1."""
    from facesculpt.nodes.input.script import ScriptNode

    gesture = tmp_path / "tap.yaml"
    gesture.write_text("steps:\n  - press: {pixel: [10, 20]}\n  - drag: {px: [5, 0], duration_s: 0.1}\n"
                       "  - release\n  - wait: 0.2\n")
    events: list[InputEvent] = []
    listener = Node(name="script_test_listener")
    listener.subscribe("input/events", InputEvent, events.append, qos=EVENTS)
    graph.node(listener)
    node = ScriptNode(params={"script": str(gesture), "loop": True, "start_delay_s": 0.5, "wait_for_face": False,
                              "wait_subscribers": 1})
    graph.node(node)
    started = time.monotonic()

    def spin(predicate, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not predicate():
            node.spin_once(0.005)
            listener.spin_once(0.005)
        return predicate()
    assert spin(lambda: node.counters.get("passes_done", 0) >= 2 and len(events) >= 10, 10)
    assert node.passes >= 2 and time.monotonic() - started >= 0.5 + 0.3
    one_pass = ["press", "drag", "drag", "drag", "release"]  # 30 Hz over 0.1 s: 3 drags
    assert [e.kind for e in events[:10]] == one_pass * 2
    assert [(e.x, e.y) for e in events[1:4]] == [(pytest.approx(10 + 5 / 3), 20), (pytest.approx(10 + 10 / 3), 20),
                                                  (15, 20)]
    assert all(e.source == "script:script" and e.handle == 2 for e in events)
    # a pixel drag from a landmark with no face to find it in: the batch run fails, status 1
    broken = tmp_path / "broken.yaml"
    broken.write_text("steps:\n  - press: chin\n  - drag: {px: [5, 0]}\n")
    out = graph.run("run", "script", f"script={broken}", "wait_for_face=false", "wait_subscribers=0",
                    "exit_when_done=true")
    assert out.returncode == 1
    assert (f"{broken} line 3: cannot find landmark 'chin' in the image: no fitted face (face/state) yet; "
            "the script stopped") in out.stderr
