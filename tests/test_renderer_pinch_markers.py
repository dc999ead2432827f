"""The renderer's pinch markers (renderer.pinch_markers): the pinches held at a frame, from the
pinch node's input events, drawn as a small marker there; the renderer as a real process marks
the pinch in render/image and, without the option, leaves the frame as it came."""

from __future__ import annotations

import numpy as np
import pytest

from facesculpt.msgs import Image, InputEvent
from facesculpt.nodes.renderer.pinch_markers import PinchMarkers, draw_pinch_markers, marker_radius
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE

MS = 1_000_000


def event(kind, stamp, handle=3, x=float("nan"), y=float("nan"), source="pinch") -> InputEvent:
    return InputEvent(stamp=stamp, kind=kind, handle=handle, x=x, y=y, source=source)


def test_markers_follow_press_drag_release_by_frame_stamp():
    m = PinchMarkers()
    for e in (event("press", 10, x=100.0, y=50.0), event("drag", 20, x=110.0, y=52.0),
              event("press", 20, handle=4, x=300.0, y=200.0), event("depth", 25),
              event("press", 25, handle=0, x=5.0, y=5.0, source="window"),  # the mouse is not a pinch
              event("release", 30, x=111.0, y=52.0), event("release", 40, handle=4)):
        m.push(e)
    assert m.at(5).shape == (0, 2)
    assert m.at(10).tolist() == [[100.0, 50.0]]
    assert m.at(25).tolist() == [[110.0, 52.0], [300.0, 200.0]]  # two hands, in handle order
    assert m.at(30).tolist() == [[300.0, 200.0]]
    assert m.at(10**12).shape == (0, 2)
    # Old events are folded into the held state, so a long pinch is still marked.
    few = PinchMarkers(max_events=4)
    few.push(event("press", 1, x=7.0, y=8.0))
    for k in range(10):
        few.push(event("drag", 2 + k, x=7.0 + k, y=8.0))
    assert len(few.events) == 4 and few.at(100).tolist() == [[16.0, 8.0]]


def test_marker_is_drawn_at_the_pinch_and_nowhere_else():
    frame = np.full((240, 320, 3), 90, np.uint8)
    assert draw_pinch_markers(frame, np.zeros((0, 2))) is frame
    out = draw_pinch_markers(frame, [[200.0, 120.0], [np.nan, 3.0]])
    assert np.array_equal(frame, np.full_like(frame, 90))  # the input is not drawn on
    changed = np.abs(out.astype(int) - frame).max(axis=2) > 0
    ys, xs = np.nonzero(changed)
    r = marker_radius(320, 240)
    assert changed.sum() > 20
    assert np.hypot(xs - 200, ys - 120).max() <= r + 4  # only around the pinch (the rim: 2 px, antialiased)
    assert tuple(out[120, 200]) != (90, 90, 90)         # the dot at its centre


class Feeder(Node):
    """Plays the camera and the pinch node for a renderer; records render/image."""

    NAME = "pinch_marker_feeder"

    def setup(self):
        self.image_pub = self.advertise("camera/image", Image)
        self.events_pub = self.advertise("input/events", InputEvent, qos=EVENTS)
        self.rendered: dict[int, np.ndarray] = {}
        self.subscribe("render/image", Image, lambda m: self.rendered.__setitem__(m.stamp, m.image),
                       qos=EVERY_MESSAGE)


def _render(graph, frame, markers: bool) -> dict[int, np.ndarray]:
    """Frames 1..3 through a renderer process: a pinch pressed at frame 2's stamp at (60, 40),
    dragged to (70, 44) at frame 3's; returns render/image by frame number."""
    renderer = graph.spawn("run", "renderer", "pairing=latest", f"pinch_markers={str(markers).lower()}")
    feeder = graph.node(Feeder())
    assert feeder.image_pub.wait_for_subscribers(1, 30.0), "the renderer never subscribed to camera/image"
    if markers:
        assert feeder.events_pub.wait_for_subscribers(1, 30.0), "the renderer never subscribed to input/events"
    feeder.events_pub.publish(event("press", 2 * 40 * MS, x=60.0, y=40.0))
    feeder.events_pub.publish(event("drag", 3 * 40 * MS, x=70.0, y=44.0))
    graph.spin_until(feeder, lambda: False, 0.5)  # the events arrive before the frames
    for i in (1, 2, 3):
        feeder.image_pub.publish(Image(stamp=i * 40 * MS, seq=i, image=frame, K=np.eye(3)))
        assert graph.spin_until(feeder, lambda: i * 40 * MS in feeder.rendered, 20.0), f"frame {i} was not rendered"
    feeder.close()
    graph.nodes.remove(feeder)
    renderer.terminate()
    renderer.wait(10)
    return {i: feeder.rendered[i * 40 * MS] for i in (1, 2, 3)}


def _marked_at(out: np.ndarray, frame: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(np.abs(out.astype(int) - frame).max(axis=2) > 30)
    return np.array([xs.mean(), ys.mean()]) if len(xs) else np.array([np.nan, np.nan])


@pytest.mark.slow
def test_renderer_marks_each_pinch_only_with_the_option(graph):
    rng = np.random.default_rng(1)
    frame = rng.integers(60, 120, (120, 160, 3), dtype=np.uint8)
    marked = _render(graph, frame, markers=True)
    assert np.array_equal(marked[1], frame)                              # before the pinch: untouched
    assert np.allclose(_marked_at(marked[2], frame), (60, 40), atol=1.0)  # at the press
    assert np.allclose(_marked_at(marked[3], frame), (70, 44), atol=1.0)  # followed the drag
    plain = _render(graph, frame, markers=False)
    assert all(np.array_equal(plain[i], frame) for i in (1, 2, 3))
