"""The hands node in a real graph: camera process (a shared hand photo) -> hands process ->
collector. Source stamps are kept, hands arrive as (N, 21, 3); a frame without a hand is an
empty message (N = 0)."""

from __future__ import annotations

import numpy as np
import pytest
from detector_checks import collect, empty_messages

from facesculpt.msgs import HandLandmarks

RUN = {"node": "hands", "topic": "hands/landmarks", "msg_type": HandLandmarks, "fps": 10}


@pytest.mark.slow
def test_node_publishes_both_hands_with_the_source_stamp(graph, models_dir, data_dir):
    images, hands = collect(graph, models_dir, data_dir / "hands" / "google_sample_woman_hands.jpg", 8, **RUN)
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


@pytest.mark.slow
def test_node_publishes_an_empty_message_when_there_is_no_hand(graph, models_dir, tmp_path):
    for msg in empty_messages(graph, models_dir, tmp_path, 4, **RUN):
        assert msg.points.shape == (0, 21, 3)
