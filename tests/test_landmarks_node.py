"""The landmarks node in a real graph: camera process -> landmarks process -> collector.
Source stamps are kept, faces arrive as (1, 468, 3), a frame without a face is an empty
message (F = 0)."""

from __future__ import annotations

import numpy as np
import pytest
from detector_checks import collect, empty_messages

from facesculpt.msgs import FaceLandmarks

RUN = {"node": "landmarks", "topic": "face/landmarks", "msg_type": FaceLandmarks, "fps": 15}


@pytest.mark.slow
def test_node_publishes_landmarks_with_the_source_stamp(graph, models_dir, data_dir):
    images, landmarks = collect(graph, models_dir, data_dir / "video" / "d0.mp4", 20, **RUN)
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


@pytest.mark.slow
def test_node_publishes_an_empty_message_when_there_is_no_face(graph, models_dir, tmp_path):
    for msg in empty_messages(graph, models_dir, tmp_path, 5, **RUN):
        assert msg.points.shape == (0, 468, 3) and msg.scores.shape == (0,) and msg.rois.shape == (0, 5)
