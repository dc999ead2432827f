"""The landmark correction mode in a real window (Xvfb, xdotool), with a real fitter process: L
shows the fit's 68 landmarks, a left-drag of the chin sends correct_landmark (and no pointer
event, so nothing is edited), the fitter then pulls its chin there on every later frame and
reports it corrected (drawn magenta), and C clears it. Needs xvfb, xdotool and x11-apps, as
tests/test_renderer_window.py, whose display fixture it uses."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
from test_renderer_window import WindowShots, _visible_window, display, xtool  # noqa: F401  (display: a fixture)

from facesculpt.nodes.renderer.correction_mode import CORRECTED_BGR, LANDMARK_BGR


def _face_feeder(frame, landmarks_points, score, roi):
    """A node playing camera + landmarks: one real frame of d0 and its detected landmarks, again
    and again at 10 Hz; it keeps the input events and face states it hears and the renderer's
    input/events subscriber count (from its diagnostics)."""
    from facesculpt.msgs import Diagnostics, FaceLandmarks, FaceState, Image, InputEvent
    from facesculpt.runtime.node import Node
    from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE

    h, w = frame.shape[:2]
    K = np.array([[w, 0, w / 2], [0, w, h / 2], [0, 0, 1.0]])

    class Feeder(Node):
        NAME = "correction_feeder"

        def setup(self):
            self.image_pub = self.advertise("camera/image", Image)
            self.landmarks_pub = self.advertise("face/landmarks", FaceLandmarks)
            self.events, self.states, self.listeners = [], [], 0
            self.subscribe("input/events", InputEvent, self.events.append, qos=EVENTS)
            self.subscribe("face/state", FaceState, self.on_state, qos=EVERY_MESSAGE)
            self.subscribe("diagnostics", Diagnostics, self.on_diagnostics, qos=EVERY_MESSAGE)
            self.timer(0.1, self.tick)

        def on_state(self, msg):
            if msg.vertices.shape[0]:
                self.states.append(msg)

        def on_diagnostics(self, msg):
            if msg.node == "renderer":
                self.listeners = msg.values.get("subscribers", {}).get("input/events", 0)

        def tick(self):
            stamp = time.time_ns()
            self.image_pub.publish(Image(stamp=stamp, image=frame, K=K))
            self.landmarks_pub.publish(FaceLandmarks(
                stamp=stamp, points=landmarks_points[None], scores=np.array([score], np.float32), rois=roi[None],
                track_ids=np.array([0], np.int32), image_size=[w, h], K=K))

    return Feeder()


def _dots(shot, points, colour) -> int:
    """How many of ``points`` (N, 2) px show a dot of ``colour`` within a pixel."""
    hits = 0
    for x, y in np.round(points[np.isfinite(points).all(axis=1)]).astype(int):
        patch = shot[y - 1:y + 2, x - 1:x + 2].reshape(-1, 3).astype(int)
        hits += bool((np.abs(patch - colour).max(axis=1) < 40).any())
    return hits


@pytest.mark.slow
def test_dragging_a_landmark_in_correction_mode_corrects_the_fit(display, graph, data_dir, models_dir):  # noqa: F811
    import cv2

    from facesculpt.nodes.landmarks import LandmarkDetector

    cap = cv2.VideoCapture(str(data_dir / "video" / "d0.mp4"))
    frame = cap.read()[1]
    cap.release()
    face = LandmarkDetector().detect(frame)[0]
    title = f"facesculpt-correct-{os.getpid()}"
    graph.env["DISPLAY"] = display
    graph.spawn("run", "fitter", "model=sfm")
    graph.spawn("run", "renderer", "window=true", "overlay=true", f"title={title}")
    feeder = graph.node(_face_feeder(frame, face.points, face.score, face.roi))
    found = []
    assert graph.spin_until(feeder, lambda: found.append(_visible_window(display, title)) or found[-1], 60.0), \
        "the renderer's window did not open"
    wid = found[-1]
    # The fitter and this feeder listen to the window's events before anything is sent.
    assert graph.spin_until(feeder, lambda: feeder.listeners == 2 and len(feeder.states) > 3, 60.0), \
        f"fitter not connected ({feeder.listeners} input/events listeners, {len(feeder.states)} states)"
    shots = WindowShots(display, wid)
    shows = shots.shows

    fitted = feeder.states[-1].landmarks
    assert fitted.shape == (68, 2) and feeder.states[-1].corrected == []
    assert not shows(lambda s: _dots(s, fitted, LANDMARK_BGR) > 20)  # editing mode: no landmarks shown
    xtool(display, "xdotool", "key", "--window", wid, "l")
    assert graph.spin_until(feeder, lambda: shows(lambda s: _dots(s, feeder.states[-1].landmarks, LANDMARK_BGR)
                                                  >= 50), 20.0), "L did not show the landmarks"

    chin = feeder.states[-1].landmarks[8].copy()
    x, y = np.round(chin).astype(int)
    target = (x + 3, y - 18)  # the chin 18 px higher (and 3 px to the side), clear of the help line
    args = ["mousemove", "--window", wid, str(x), str(y), "mousedown", "1"]
    for k in (1, 2, 3, 4, 5, 6):
        args += ["mousemove", "--window", wid, str(x + k * 3 // 6), str(y - k * 3), "sleep", "0.05"]
    args += ["mouseup", "1"]
    xtool(display, "xdotool", *args)
    sent = lambda: [e for e in feeder.events if e.command == "correct_landmark"]  # noqa: E731
    assert graph.spin_until(feeder, lambda: sent() and abs(sent()[-1].y - target[1]) <= 1, 10.0), \
        [(e.kind, e.command, e.y) for e in feeder.events]
    assert all(e.argument == "9" and e.source == "window" and e.face == 0 for e in sent())
    assert abs(sent()[-1].x - target[0]) <= 1
    # Nothing a deformer would act on: no press, drag or release left the window.
    assert not [e for e in feeder.events if e.kind != "command"], [e.kind for e in feeder.events]

    # The fitter took it: later states say so and put their chin at the dragged point.
    n = len(feeder.states)
    assert graph.spin_until(feeder, lambda: len(feeder.states) > n + 3 and feeder.states[-1].corrected == [9], 20.0)
    moved = feeder.states[-1].landmarks[8]
    assert np.linalg.norm(moved - target) < 0.5 * np.linalg.norm(chin - target), (chin, moved, target)
    assert graph.spin_until(feeder, lambda: shows(lambda s: _dots(s, feeder.states[-1].landmarks[8:9], CORRECTED_BGR)
                                                  == 1), 10.0), "the corrected chin is not drawn magenta"

    # C clears the corrections: the chin goes back toward where the network sees it (the SFM keeps
    # part of the identity it accumulated meanwhile).
    xtool(display, "xdotool", "key", "--window", wid, "c")
    assert graph.spin_until(feeder, lambda: feeder.states[-1].corrected == [] and np.linalg.norm(
        feeder.states[-1].landmarks[8] - chin) < 0.5 * np.linalg.norm(moved - chin), 20.0), \
        (chin, moved, feeder.states[-1].landmarks[8], feeder.states[-1].corrected)
