"""The hands node in a real graph: camera process (a shared hand photo) -> hands process ->
collector. Source stamps are kept, hands arrive as (N, 21, 3); a frame without a hand is an
empty message (N = 0)."""

from __future__ import annotations

import cv2
import numpy as np

from facesculpt.msgs import HandLandmarks, Image
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVERY_MESSAGE


def _collect(graph, models_dir, source, frames, timeout=60):
    images, hands = {}, []
    node = graph.node(Node(name="hands_collector"))
    node.subscribe("camera/image", Image, lambda m: images.__setitem__(m.stamp, m.image.shape), qos=EVERY_MESSAGE)
    node.subscribe("hands/landmarks", HandLandmarks, hands.append, qos=EVERY_MESSAGE)
    graph.spawn("run", "hands", f"models_dir={models_dir}")
    cam = graph.spawn("run", "camera", f"source={source}", "fps=10", f"max_frames={frames}", "wait_subscribers=2",
                      "wait_timeout_s=30")
    graph.spin_until(node, lambda: cam.poll() is not None and hands and hands[-1].stamp == max(images), timeout)
    node.spin_once(0.5)
    return images, hands


def test_node_publishes_both_hands_with_the_source_stamp(graph, models_dir, data_dir):
    images, hands = _collect(graph, models_dir, data_dir / "hands" / "google_sample_woman_hands.jpg", 8)
    assert len(images) == 8 and len(hands) >= 4
    assert [m.stamp for m in hands] == sorted(m.stamp for m in hands) and {m.stamp for m in hands} <= set(images)
    for msg in hands:
        assert msg.points.shape == (2, 21, 3) and msg.points.dtype == np.float32
        assert msg.scores.shape == (2,) and msg.scores.min() > 0.5
        assert sorted(msg.track_ids.tolist()) == [0, 1]
        h, w = images[msg.stamp][:2]
        assert msg.image_size == [w, h]
        left, right = sorted(range(2), key=lambda i: msg.points[i, 0, 0])
        assert msg.right[left] < 0.5 < msg.right[right]  # her left hand at the bottom left, her right on top


def test_node_publishes_an_empty_message_when_there_is_no_hand(graph, models_dir, tmp_path):
    grey = tmp_path / "grey.png"
    cv2.imwrite(str(grey), np.full((240, 320, 3), 127, np.uint8))
    images, hands = _collect(graph, models_dir, grey, 4)
    assert hands
    for msg in hands:
        assert msg.stamp in images and msg.points.shape == (0, 21, 3) and msg.image_size == [320, 240]
