"""The window's landmark correction mode as plain state (facesculpt/nodes/renderer/correction_mode.py): the
fit's 68 landmarks from a face state, picking the nearest, a drag sent as throttled
correct_landmark commands, the points drawn (corrected ones in another colour) with the name of
the one under the cursor. The real window and graph: tests/test_renderer_window.py."""

from __future__ import annotations

import numpy as np

from facesculpt.msgs import FaceState, InputEvent, decode, encode
from facesculpt.nodes.renderer.correction_mode import CORRECTED_BGR, LANDMARK_BGR, CorrectionMode, landmark_name


def _state(face_id=0, corrected=()):
    k = np.arange(68)
    points = np.stack([60.0 + 40 * (k % 10), 60.0 + 40 * (k // 10)], axis=1).astype(np.float32)  # 40 px apart
    points[60] = np.nan  # a landmark the fit has none for (the SFM's inner mouth corners)
    return FaceState(stamp=1, vertices=np.zeros((3, 3), np.float32), projected=np.zeros((3, 2), np.float32),
                     face_id=face_id, landmarks=points, corrected=list(corrected))


def test_names_of_the_68_landmarks():
    names = [landmark_name(k) for k in range(1, 69)]
    assert len(set(names)) == 68
    assert names[8] == "9 chin" and names[30] == "31 nose tip" and names[19] == "20 right eyebrow 3"
    assert landmark_name(36).startswith("36 nose base")


def test_the_state_carries_the_landmarks_over_the_wire():
    msg = decode(encode(_state(corrected=[9, 31]), "face/state"), FaceState)[1]
    assert msg.landmarks.shape == (68, 2) and msg.corrected == [9, 31]
    plain = decode(encode(FaceState(stamp=1), "face/state"), FaceState)[1]  # older publishers: no landmarks
    assert plain.landmarks is None and plain.corrected == []


def test_a_drag_becomes_throttled_correct_landmark_commands():
    mode = CorrectionMode(send_period_s=0.1)
    mode.observe([_state(face_id=3)])
    x, y = mode.landmarks[3][30]
    assert mode.nearest(x + 5, y + 5) == (3, 31)
    assert mode.nearest(x + 20, y + 20) is None                  # too far from any landmark
    assert mode.handle({"kind": "press", "x": x + 2, "y": y}, 0.0) == []
    sent = mode.handle({"kind": "drag", "x": x, "y": y + 10}, 0.01)
    sent += mode.handle({"kind": "drag", "x": x, "y": y + 12}, 0.05)    # within the period: held back
    sent += mode.handle({"kind": "drag", "x": x, "y": y + 15}, 0.2)
    sent += mode.handle({"kind": "release", "x": x, "y": y + 20}, 0.21)  # the release is always sent
    assert [(e["argument"], e["y"] - y, e["face"]) for e in sent] == [("31", 10, 3), ("31", 15, 3), ("31", 20, 3)]
    event = InputEvent(source="window", **sent[-1])
    assert event.kind == "command" and event.command == "correct_landmark"
    assert mode.drag is None
    # A press on no landmark drags nothing.
    mode.handle({"kind": "press", "x": 5.0, "y": 5.0}, 1.0)
    assert mode.handle({"kind": "release", "x": 50.0, "y": 50.0}, 1.1) == []


def test_the_landmarks_are_drawn_and_the_one_under_the_cursor_named():
    mode = CorrectionMode()
    mode.observe([_state(corrected=[9])])
    image = np.full((400, 500, 3), 90, np.uint8)
    out = mode.draw(image)
    points = mode.landmarks[0]
    for k, colour in ((1, LANDMARK_BGR), (9, CORRECTED_BGR)):
        x, y = np.round(points[k - 1]).astype(int)
        assert tuple(out[y, x]) == colour
    x, y = np.round(points[30]).astype(int)
    labelled = mode.draw(image, pointer=(x + 3.0, y))
    label = (slice(y - 30, y - 2), slice(x + 8, min(500, x + 120)))
    assert np.abs(labelled[label].astype(int) - out[label]).sum() > 1000  # "31 nose tip" written there
    assert np.array_equal(image, np.full((400, 500, 3), 90, np.uint8))   # the input is left alone
