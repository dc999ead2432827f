"""The renderer node as a real process in a graph: real frames and face states in, the composited
frames out on render/image and in a video file, per-stage times in diagnostics."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from benchmarks.renderer_scene import issue_edit, place_marked, read_frames
from facesculpt.geometry import merge_deformation
from facesculpt.msgs import Deformation, Diagnostics, FaceModel, FaceState, FrameDone, Image
from facesculpt.nodes.renderer import Compositor
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE, LATCHED

MS = 1_000_000


class Feeder(Node):
    """Plays the camera, the fitter and the deformer for the renderer; records what comes back."""

    NAME = "renderer_feeder"

    def setup(self):
        self.image_pub = self.advertise("camera/image", Image)
        self.state_pub = self.advertise("face/state", FaceState)
        self.model_pub = self.advertise("face/model", FaceModel, qos=LATCHED)
        self.deformation_pub = self.advertise("face/deformation", Deformation)
        self.rendered: dict[int, np.ndarray] = {}
        self.diagnostics_seen: list[dict] = []
        self.subscribe("render/image", Image, self.on_render, qos=EVERY_MESSAGE)
        self.subscribe("diagnostics", Diagnostics, self.on_diagnostics, qos=EVERY_MESSAGE)

    def on_render(self, msg):
        self.rendered[msg.stamp] = msg.image

    def on_diagnostics(self, msg):
        if msg.node == "renderer":
            self.diagnostics_seen.append(msg.values)


@pytest.mark.parametrize("plate", ["off", "on"])
@pytest.mark.slow
def test_renderer_node_pairs_composites_and_writes_video(plate, graph, data_dir, tmp_path, request):
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.renderer.person_segmentation import PersonSegmenter

    model = load_model("sfm")
    pose = place_marked(model, "s18")
    edit = issue_edit(pose).astype(np.float32)
    frames = read_frames(data_dir, "s18", count=5)
    H, W = frames[0].shape[:2]
    video = tmp_path / "out.avi"
    # with the plate on, the node finds the people of each frame from its arrival (prefetch)
    segmenter = PersonSegmenter(request.getfixturevalue("models_dir")) if plate == "on" else None
    renderer = graph.spawn("run", "renderer", "pairing=sync", f"output={video}", "fps=25", f"plate={plate}")
    feeder = graph.node(Feeder())
    for pub in (feeder.image_pub, feeder.state_pub, feeder.deformation_pub):
        assert pub.wait_for_subscribers(1, 30.0), f"the renderer never subscribed to {pub.topic}"
    feeder.model_pub.publish(FaceModel(stamp=1, model_id=model.model_id, vertices=model.mean.astype(np.float32),
                                       triangles=model.triangles.astype(np.int32)))
    feeder.deformation_pub.publish(Deformation(stamp=1, model_id=model.model_id, displacement=edit, version=1))
    graph.spin_until(feeder, lambda: False, 1.0)  # let model and edit arrive before the frames

    no_face = 2
    for i, frame in enumerate(frames):
        stamp = (i + 1) * 40 * MS
        feeder.image_pub.publish(Image(stamp=stamp, seq=i, image=frame, K=pose.K))
        if i == no_face:  # the fitter found no face in this frame
            state = FaceState(stamp=stamp, model_id=model.model_id, vertices=np.zeros((0, 3), np.float32),
                              projected=np.zeros((0, 2), np.float32), image_size=[W, H])
        else:
            state = FaceState(stamp=stamp, model_id=model.model_id, R=pose.R, t=np.zeros(3), scale=1.0, K=pose.K,
                              vertices=pose.fitted.astype(np.float32), projected=pose.projected.astype(np.float32),
                              image_size=[W, H], projection="perspective")
        feeder.state_pub.publish(state)
        # One frame at a time, as a camera would: a burst of 1.2 MB frames overflows the
        # publisher's small high-water mark (latest-only by design).
        assert graph.spin_until(feeder, lambda: len(feeder.rendered) == i + 1, 20.0), \
            f"frame {i} was not rendered"

    # Each frame comes back composited exactly as the library composites it (Eq. 5 merge of the
    # edit into the state's pose, then the compositor); the faceless one unchanged, bit for bit.
    comp = Compositor(W, H, plate=plate == "on", segmenter=segmenter)  # the library's defaults: the live renderer's
    for i, frame in enumerate(frames):
        out = feeder.rendered[(i + 1) * 40 * MS]
        if i == no_face:
            assert np.array_equal(out, frame)
            continue
        deformed = merge_deformation(pose.fitted.astype(np.float32), pose.R, 1.0, edit)
        expected = comp.render(frame, pose.fitted.astype(np.float32), pose.projected.astype(np.float32),
                               model.triangles, deformed)
        assert not np.array_equal(out, frame)
        assert np.abs(out.astype(int) - expected).max() <= 1
    if plate == "on":
        assert comp.plate.known().any()
    comp.release()

    # Diagnostics carry the per-stage times and what happened.
    assert graph.spin_until(feeder, lambda: any(d["counters"].get("rendered") == 5 for d in feeder.diagnostics_seen),
                            15.0)
    stages = {k for d in feeder.diagnostics_seen for k in d["stages_ms"]}
    assert {"pair", "merge", "camera", "texture", "draw", "readback", "inpaint", "composite", "output"} <= stages
    counters = feeder.diagnostics_seen[-1]["counters"]
    assert counters["no_face"] == 1 and counters["pairing_passed_without_face"] == 1

    # The video file holds the same frames (after a clean stop).
    renderer.terminate()
    assert renderer.wait(10) == 0
    cap = cv2.VideoCapture(str(video))
    written = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        written.append(f)
    assert len(written) == len(frames)
    mse = np.mean((written[no_face].astype(float) - frames[no_face]) ** 2)
    assert 10 * np.log10(255 ** 2 / mse) > 28


class BurstFeeder(Node):
    """Sends every frame it is given (no frame dropped on the way) and records what comes back."""

    NAME = "renderer_burst_feeder"

    def setup(self):
        self.image_pub = self.advertise("camera/image", Image, qos=EVENTS)  # reliable: blocks, never drops
        self.state_pub = self.advertise("face/state", FaceState, qos=EVENTS)
        self.model_pub = self.advertise("face/model", FaceModel, qos=LATCHED)
        self.rendered: list[int] = []
        self.done: list = []
        self.subscribe("render/image", Image, lambda m: self.rendered.append(m.stamp), qos=EVERY_MESSAGE)
        self.subscribe("render/done", FrameDone, self.done.append, qos=EVERY_MESSAGE)


@pytest.mark.slow
def test_a_renderer_that_falls_behind_renders_only_the_newest_frame_unless_told_to_keep_all(graph, data_dir):
    from facesculpt.nodes.fitter import load_model

    model = load_model("sfm")
    pose = place_marked(model, "s18")
    frame = read_frames(data_dir, "s18", count=1)[0]
    H, W = frame.shape[:2]
    feeder = graph.node(BurstFeeder())
    feeder.model_pub.publish(FaceModel(stamp=1, model_id=model.model_id, vertices=model.mean.astype(np.float32),
                                       triangles=model.triangles.astype(np.int32)))
    rendered = {}
    before: set[str] = set()  # the previous renderer's render/image and render/done endpoints
    for run, backlog in enumerate(("auto", "all")):
        renderer = graph.spawn("run", "renderer", "pairing=sync", f"backlog={backlog}", "--name", f"renderer{run}")
        # This renderer connected both ways (the previous one's subscriptions are gone, below): it
        # takes the frames and states, and the feeder hears its render/image and render/done.
        for pub in (feeder.image_pub, feeder.state_pub):
            assert pub.wait_for_subscribers(1, 60.0), f"the renderer never subscribed to {pub.topic}"
        assert graph.spin_until(feeder, lambda: all(s.endpoints and not s.endpoints & before
                                                    for s in feeder.subscriptions), 30.0), "renderer not heard"
        before = set().union(*(s.endpoints for s in feeder.subscriptions))
        graph.spin_until(feeder, lambda: False, 1.0)
        feeder.rendered.clear()
        feeder.done.clear()
        stamps = [(run * 100 + i + 1) * 40 * MS for i in range(12)]
        for stamp in stamps:  # the states first (a fitter ahead of the frames' delivery), then a burst of frames
            feeder.state_pub.publish(FaceState(stamp=stamp, model_id=model.model_id, R=pose.R, t=np.zeros(3), K=pose.K,
                                               vertices=pose.fitted.astype(np.float32),
                                               projected=pose.projected.astype(np.float32), image_size=[W, H]))
        graph.spin_until(feeder, lambda: False, 0.5)
        for i, stamp in enumerate(stamps):  # a 300 frames/s camera: faster than the renderer draws
            feeder.image_pub.publish(Image(stamp=stamp, seq=i, image=frame, K=pose.K))
            time.sleep(0.0033)
        assert graph.spin_until(feeder, lambda: len(feeder.done) == len(stamps) and len(feeder.rendered)
                                == sum(d.rendered for d in feeder.done), 30.0), (backlog, len(feeder.done))
        rendered[backlog] = list(feeder.rendered)
        assert sorted(d.stamp for d in feeder.done) == stamps  # every frame acknowledged, rendered or not
        assert sum(not d.rendered for d in feeder.done) == len(stamps) - len(feeder.rendered)
        renderer.terminate()
        renderer.wait(10)
        # Until its subscriptions are gone, the next renderer's wait_for_subscribers would count them.
        assert graph.spin_until(feeder, lambda: feeder.image_pub.subscriber_count() == 0
                                and feeder.state_pub.subscriber_count() == 0, 30.0)
    # Live (no video file): the frames that queued up while it rendered are skipped, the newest drawn.
    assert 1 <= len(rendered["auto"]) < 12 and rendered["auto"][-1] == (0 * 100 + 12) * 40 * MS
    assert rendered["all"] == [(100 + i + 1) * 40 * MS for i in range(12)]  # backlog=all: every one, in order
