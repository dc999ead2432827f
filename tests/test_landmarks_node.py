"""The landmarks node in a real graph: camera process -> landmarks process -> collector.
Source stamps are kept, faces arrive as (1, 468, 3), a frame without a face is an empty
message (F = 0)."""

from __future__ import annotations

import cv2
import numpy as np

from facesculpt.msgs import FaceLandmarks, Image
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVERY_MESSAGE


def _collect(graph, models_dir, source, frames, timeout=60):
    images, landmarks = {}, []
    node = graph.node(Node(name="landmarks_collector"))
    node.subscribe("camera/image", Image, lambda m: images.__setitem__(m.stamp, m.image.shape), qos=EVERY_MESSAGE)
    node.subscribe("face/landmarks", FaceLandmarks, landmarks.append, qos=EVERY_MESSAGE)
    graph.spawn("run", "landmarks", f"models_dir={models_dir}")
    # The camera waits for both subscribers (collector and landmarks) before its first frame.
    cam = graph.spawn("run", "camera", f"source={source}", "fps=15", f"max_frames={frames}", "wait_subscribers=2",
                      "wait_timeout_s=30")
    graph.spin_until(node, lambda: cam.poll() is not None and landmarks and landmarks[-1].stamp == max(images), timeout)
    node.spin_once(0.5)
    return images, landmarks


def test_node_publishes_landmarks_with_the_source_stamp(graph, models_dir, data_dir):
    images, landmarks = _collect(graph, models_dir, data_dir / "video" / "d0.mp4", 20)
    assert len(images) == 20
    assert len(landmarks) >= 10  # latest-only: a slow moment may skip a frame, never reorder
    stamps = [m.stamp for m in landmarks]
    assert stamps == sorted(stamps) and set(stamps) <= set(images)
    for msg in landmarks:
        assert msg.points.shape == (1, 468, 3) and msg.points.dtype == np.float32
        assert msg.scores.shape == (1,) and msg.scores[0] > 0.5
        assert msg.rois.shape == (1, 5)
        h, w = images[msg.stamp][:2]
        assert msg.image_size == [w, h]
        assert np.all((msg.points[0, :, 0] > 0) & (msg.points[0, :, 0] < w))


def test_node_publishes_an_empty_message_when_there_is_no_face(graph, models_dir, tmp_path):
    grey = tmp_path / "grey.png"
    cv2.imwrite(str(grey), np.full((240, 320, 3), 127, np.uint8))
    images, landmarks = _collect(graph, models_dir, grey, 5)
    assert landmarks
    for msg in landmarks:
        assert msg.stamp in images
        assert msg.points.shape == (0, 468, 3) and msg.scores.shape == (0,) and msg.rois.shape == (0, 5)
        assert msg.image_size == [320, 240]
