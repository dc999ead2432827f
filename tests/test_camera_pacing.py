"""The live camera paced by the renderer's acknowledgements (issue 22: a graph that cannot keep
the camera's rate spends no work on frames it would not render), and its halved copy for the
analysis path (camera/analysis), tracked by the landmarks node in the full frame's pixels."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest
from test_offline_every_frame import _video_frames, _write_bag

from facesculpt.geometry.halving import halve, halved_intrinsics
from facesculpt.msgs import FrameDone, Image
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVERY_MESSAGE


def _index(image: np.ndarray) -> int:
    """The number a frame of the numbered bag carries (frame i is filled with 4 * i)."""
    return int(round(float(image[0, 0, 0]) / 4))


@pytest.mark.slow
def test_paced_camera_sends_the_newest_frame_on_each_acknowledgement(graph, tmp_path):
    bag = tmp_path / "numbers.bag"
    _write_bag(bag, [np.full((48, 64, 3), 4 * i, np.uint8) for i in range(60)])
    arrivals: list[tuple[float, int, int, int]] = []   # (monotonic, seq, stamp, frame index)
    acked: dict[int, float] = {}                       # seq -> monotonic time of its acknowledgement
    acker = graph.node(Node(name="acker"))
    done = acker.advertise("render/done", FrameDone, qos=EVERY_MESSAGE)
    acker.subscribe("camera/image", Image, qos=EVERY_MESSAGE,
                    callback=lambda m: arrivals.append((time.monotonic(), m.seq, m.stamp, _index(m.image))))
    # 30 frames/s from the bag; this "renderer" takes 100 ms a frame and acknowledges none of the
    # frames that carry an index from 30 to 44 (the camera gives them up after pace_timeout_s).
    # pace_reads=off: read at the bag's pace, as a webcam's frames come whether read or not
    cam = graph.spawn("run", "camera", f"source=bag:{bag}", "fps=30", "pace_by=render/done", "pace_in_flight=2",
                      "pace_timeout_s=0.5", "wait_subscribers=1", "pace_reads=off")
    deadline = time.monotonic() + 30
    while cam.poll() is None and time.monotonic() < deadline:
        acker.spin_once(0.01)
        now = time.monotonic()
        for t, seq, stamp, index in list(arrivals):
            if seq not in acked and not 30 <= index < 45 and now - t >= 0.1:
                done.publish(FrameDone(stamp=stamp, seq=seq, frame_id="camera", rendered=True))
                acked[seq] = time.monotonic()
    assert cam.poll() == 0, "the camera did not end at the end of its bag"

    indices = [i for _, _, _, i in arrivals]
    assert indices == sorted(indices) and len(set(indices)) == len(indices), indices
    assert 10 <= len(arrivals) <= 40, f"{len(arrivals)} of 60 frames went out at ~10 acknowledgements a second"

    def released(seq: int, arrived: float) -> float:
        """When the camera stopped waiting for ``seq``: its acknowledgement or a later frame's
        (older frames are then known skipped), else its timeout (which runs from its sending, a
        little before its arrival here)."""
        return min([a for q, a in acked.items() if q >= seq] + [arrived + 0.45])

    for t, seq, _, _ in arrivals:  # never more than pace_in_flight unacknowledged
        waiting = [q for t2, q, _, _ in arrivals if t2 < t and released(q, t2) > t]
        assert len(waiting) <= 1, (seq, waiting)
    # Each frame that went out on an acknowledgement was the newest one read: its stamp is at
    # most about one frame period (33 ms) older than its arrival, not a queue's length.
    ages = [(t * 1e9 - time.monotonic_ns() + time.time_ns() - stamp) / 1e6 for t, _, stamp, _ in arrivals]
    assert np.median(ages) < 40, ages
    held = [t for t, _, _, i in arrivals if 30 <= i < 45]  # sent at once: two may be in flight
    following = [t for t, _, _, i in arrivals if t > held[-1]]
    assert len(held) == 2 and following and following[0] - held[0] >= 0.45, \
        "frames nobody acknowledged did not hold the next ones until their timeout"


@pytest.mark.slow
def test_a_renderer_slower_than_the_pace_timeout_is_waited_for(graph, tmp_path):
    """A "renderer" that takes 0.8 s a frame on a loaded machine, beyond pace_timeout_s (0.5 s):
    once a few acknowledgements have come, the camera waits for it (the timeout follows their
    round trips), so no third frame goes in while two are still being rendered."""
    bag = tmp_path / "numbers.bag"
    _write_bag(bag, [np.full((48, 64, 3), 4 * i, np.uint8) for i in range(14)])
    arrivals: list[tuple[float, int, int]] = []   # (monotonic, seq, stamp)
    acked: dict[int, float] = {}
    acker = graph.node(Node(name="acker"))
    done = acker.advertise("render/done", FrameDone, qos=EVERY_MESSAGE)
    acker.subscribe("camera/image", Image, qos=EVERY_MESSAGE,
                    callback=lambda m: arrivals.append((time.monotonic(), m.seq, m.stamp)))
    cam = graph.spawn("run", "camera", f"source=bag:{bag}", "fps=30", "pace_by=render/done", "pace_in_flight=2",
                      "pace_timeout_s=0.5", "wait_subscribers=1")
    deadline = time.monotonic() + 60
    while cam.poll() is None and time.monotonic() < deadline:
        acker.spin_once(0.01)
        for t, seq, stamp in list(arrivals):
            if seq not in acked and time.monotonic() - t >= 0.8:
                done.publish(FrameDone(stamp=stamp, seq=seq, frame_id="camera", rendered=True))
                acked[seq] = time.monotonic()
    assert cam.poll() == 0, "the camera did not end at the end of its bag"
    assert len(arrivals) == 14
    # After the first four acknowledgements: at each arrival, at most one older frame unacknowledged.
    settled = sorted(acked.values())[3]
    crowded = [seq for t, seq, _ in arrivals if t > settled
               and sum(1 for t2, q, _ in arrivals if t2 < t and acked.get(q, 1e18) > t) > 1]
    assert not crowded, f"frames {crowded} went in while two were still being rendered"


@pytest.mark.slow
def test_paced_file_camera_reads_a_frame_only_when_it_may_go_out(graph, tmp_path):
    """A recorded source (here a bag) behind a renderer slower than its rate: no frame is read to be
    dropped (every frame goes out, in order), never more than pace_in_flight wait, and each goes
    out as it is read (its age at arrival is not the wait for an acknowledgement)."""
    bag = tmp_path / "numbers.bag"
    _write_bag(bag, [np.full((48, 64, 3), 4 * i, np.uint8) for i in range(24)])
    arrivals: list[tuple[float, int, int, int]] = []   # (monotonic, seq, stamp, frame index)
    acked: dict[int, float] = {}
    acker = graph.node(Node(name="acker"))
    done = acker.advertise("render/done", FrameDone, qos=EVERY_MESSAGE)
    acker.subscribe("camera/image", Image, qos=EVERY_MESSAGE,
                    callback=lambda m: arrivals.append((time.monotonic(), m.seq, m.stamp, _index(m.image))))
    cam = graph.spawn("run", "camera", f"source=bag:{bag}", "fps=60", "pace_by=render/done", "pace_in_flight=2",
                      "wait_subscribers=1")
    deadline = time.monotonic() + 30
    while cam.poll() is None and time.monotonic() < deadline:
        acker.spin_once(0.01)
        now = time.monotonic()
        for t, seq, stamp, _ in list(arrivals):
            if seq not in acked and now - t >= 0.08:   # an 80 ms "renderer": 25 frames/s with two in flight
                done.publish(FrameDone(stamp=stamp, seq=seq, frame_id="camera", rendered=True))
                acked[seq] = time.monotonic()
    assert cam.poll() == 0, "the camera did not end at the end of its bag"
    assert [i for _, _, _, i in arrivals] == list(range(24))   # none read and dropped
    for t, seq, _, _ in arrivals:
        waiting = [q for t2, q, _, _ in arrivals if t2 < t and acked.get(q, 1e18) > t]
        assert len(waiting) <= 1, (seq, waiting)
    ages = [(t * 1e9 - time.monotonic_ns() + time.time_ns() - stamp) / 1e6 for t, _, stamp, _ in arrivals]
    assert np.median(ages) < 10, ages


@pytest.mark.slow
def test_camera_publishes_a_halved_copy_for_the_analysis_path(graph, tmp_path):
    bag = tmp_path / "big.bag"
    _write_bag(bag, [np.random.default_rng(i).integers(0, 256, (1081, 1921, 3), np.uint8) for i in range(3)])
    got: dict[str, list[Image]] = {"camera/image": [], "camera/analysis": []}
    listener = graph.node(Node(name="listener"))
    for topic in got:
        listener.subscribe(topic, Image, callback=got[topic].append, qos=EVERY_MESSAGE)
    cam = graph.spawn("run", "camera", f"source=bag:{bag}", "fps=10", "analysis_pixels=300000",
                      "wait_subscribers=1", "pace_by=")  # one listener of both topics
    deadline = time.monotonic() + 30
    while cam.poll() is None and time.monotonic() < deadline:
        listener.spin_once(0.02)
    listener.spin_once(0.2)
    assert cam.poll() == 0
    full, analysis = got["camera/image"], got["camera/analysis"]
    assert len(full) == len(analysis) == 3
    for f, a in zip(full, analysis):
        assert (a.stamp, a.seq) == (f.stamp, f.seq)
        assert a.halvings == 2 and a.frame_size == [1921, 1081] and a.image.shape == (270, 480, 3)
        np.testing.assert_array_equal(a.image, halve(f.image, 2))
        np.testing.assert_allclose(a.K, halved_intrinsics(f.K, 2))
        assert f.halvings == 0


def test_landmarks_on_the_halved_copy_are_in_the_frames_pixels(data_dir, models_dir, monkeypatch, tmp_path):
    from facesculpt.nodes.landmarks.node import LandmarksNode

    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    frames = [cv2.resize(f, (2048, 1152), interpolation=cv2.INTER_CUBIC)
              for f in _video_frames(data_dir / "video" / "s18.mp4", 12)]
    K = np.array([[1800.0, 0, 1023.5], [0, 1800.0, 575.5], [0, 0, 1]])
    results = {}
    for name, params in (("full", {"max_pixels": 0}), ("copy", {"image_topic": "camera/analysis"})):
        node = LandmarksNode(params={"models_dir": str(models_dir), **params})
        node.setup()
        sent = []
        node.pub.publish = sent.append
        try:
            for i, frame in enumerate(frames):
                if name == "full":
                    msg = Image(stamp=i + 1, seq=i + 1, frame_id="camera", image=frame, K=K)
                else:
                    msg = Image(stamp=i + 1, seq=i + 1, frame_id="camera", image=halve(frame, 1),
                                K=halved_intrinsics(K, 1), halvings=1, frame_size=[2048, 1152])
                node.on_image(msg)
        finally:
            node.close()
        results[name] = sent
    for a, b in zip(results["full"], results["copy"]):
        assert a.image_size == b.image_size == [2048, 1152] and a.points.shape == b.points.shape == (1, 468, 3)
        np.testing.assert_allclose(b.K, K)
        eyes = np.linalg.norm(a.points[0, 33, :2] - a.points[0, 263, :2])
        assert np.median(np.linalg.norm(a.points[0, :, :2] - b.points[0, :, :2], axis=1)) < 0.02 * eyes
    # a copy whose frame size cannot be its frame's is dropped and counted, not tracked
    node = LandmarksNode(params={"models_dir": str(models_dir), "image_topic": "camera/analysis"})
    node.setup()
    sent = []
    node.pub.publish = sent.append
    try:
        node.on_image(Image(stamp=1, seq=1, image=halve(frames[0], 1), K=K, halvings=1, frame_size=[640, 480]))
    finally:
        node.close()
    assert node.counters.get("bad_image") == 1 and sent[0].points.shape[0] == 0
