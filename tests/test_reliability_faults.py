"""Faults at the edges: a corrupt or truncated video, frames that change size mid-stream,
a full disk or an unwritable path while recording a bag or writing a video."""

from __future__ import annotations

import subprocess
import time

import cv2
import numpy as np
import pytest

from facesculpt.msgs import Diagnostics, FaceState, Image, decode
from facesculpt.nodes.renderer.video_out import VideoOutput
from facesculpt.runtime.bag import BagReader, BagWriter
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVERY_MESSAGE


@pytest.fixture
def small_disk(tmp_path):
    """A 3 MiB tmpfs (needs root); skips where it cannot be mounted."""
    mount = tmp_path / "small"
    mount.mkdir()
    out = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=3m", "tmpfs", str(mount)], capture_output=True)
    if out.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here: {out.stderr.decode().strip()}")
    yield mount
    subprocess.run(["umount", "-l", str(mount)])


@pytest.mark.slow
def test_corrupt_and_truncated_videos_are_reported_and_end_cleanly(graph, data_dir, tmp_path):
    data = bytearray((data_dir / "video" / "d3.mp4").read_bytes())
    rng = np.random.default_rng(0)
    a, b = int(len(data) * 0.4), int(len(data) * 0.5)
    garbled = tmp_path / "garbled.mp4"
    garbled.write_bytes(bytes(data[:a]) + rng.integers(0, 256, b - a, dtype=np.uint8).tobytes() + bytes(data[b:]))
    got: list[Image] = []
    watcher = graph.node(Node(name="watcher"))
    watcher.subscribe("camera/image", Image, got.append, qos=EVERY_MESSAGE)
    cam = graph.spawn("run", "camera", f"source={garbled}", "fps=60", "wait_subscribers=1", "pace_by=",
                      stderr=subprocess.PIPE)
    assert graph.spin_until(watcher, lambda: cam.poll() is not None, 60), "the camera did not end"
    err = cam.stderr.read().decode()
    assert cam.returncode == 0, err[-2000:]
    assert "corrupt or truncated" in err and "of 354" in err, err[-2000:]
    assert 0 < len(got) < 354 and all(m.image.shape == (512, 512, 3) for m in got)

    cut = tmp_path / "cut.mp4"
    cut.write_bytes(bytes(data[: len(data) // 2]))
    out = graph.run("run", "camera", f"source={cut}")
    assert out.returncode == 2 and f"cannot open video file {cut}" in out.stderr  # a configuration error


@pytest.mark.slow
def test_frames_of_a_new_size_flow_through_the_graph(graph, data_dir, models_dir, tmp_path):
    """A bag of two videos of different sizes (512x512, then 1280x720) through camera,
    landmarks, fitter and renderer: every stage follows the new size, nothing errs."""
    bag = tmp_path / "two_sizes.bag"
    with BagWriter(bag) as writer:
        t = time.time_ns()
        for name, n in (("d3.mp4", 25), ("s18.mp4", 25)):
            cap = cv2.VideoCapture(str(data_dir / "video" / name))
            for _ in range(n):
                ok, frame = cap.read()
                assert ok
                t += 66_000_000
                writer.write(t, "camera/image", Image(stamp=t, image=frame).to_frames())
    sizes_render, sizes_state = set(), set()
    diags: dict = {}
    watcher = graph.node(Node(name="watcher"))
    watcher.subscribe("render/image", Image, lambda m: sizes_render.add(m.image.shape[:2]), qos=EVERY_MESSAGE)
    watcher.subscribe("face/state", FaceState, lambda m: sizes_state.add(tuple(m.image_size)), qos=EVERY_MESSAGE)
    watcher.subscribe("diagnostics", Diagnostics, lambda m: diags.__setitem__(m.node, m.values))
    procs = [graph.spawn("run", "landmarks"), graph.spawn("run", "fitter"),
             graph.spawn("run", "renderer", "pairing=latest", "output=")]
    assert graph.spin_until(watcher, lambda: {"landmarks", "fitter", "renderer"} <= set(diags), 60)
    cam = graph.spawn("run", "camera", f"source=bag:{bag}", "fps=10", "wait_subscribers=2")
    assert graph.spin_until(watcher, lambda: cam.poll() is not None, 60)
    graph.spin_until(watcher, lambda: False, 3.0)
    assert {(512, 512), (720, 1280)} <= sizes_render, sizes_render
    assert {(512, 512), (1280, 720)} <= sizes_state, sizes_state
    assert all(p.poll() is None for p in procs), "a node died"
    for name in ("landmarks", "fitter", "renderer"):
        assert diags[name]["errors"] == 0, (name, diags[name]["last_error"])


@pytest.mark.slow
def test_bag_record_on_a_full_disk_keeps_what_was_written(graph, data_dir, small_disk):
    bag = small_disk / "full.bag"
    rec = graph.spawn("bag", "record", "camera/image", "-o", str(bag), "--count", "50", stderr=subprocess.PIPE)
    graph.spawn("run", "camera", f"source={data_dir / 'video' / 'd3.mp4'}", "fps=30", "max_frames=50",
                "wait_subscribers=1", "pace_by=")
    assert rec.wait(60) == 1
    err = rec.stderr.read().decode()
    assert "No space left on device" in err and "records before it are readable" in err, err
    records = list(BagReader(bag))
    assert 1 <= len(records) < 50
    for r in records:
        _, msg = decode([r.topic.encode()] + r.frames, Image)
        assert msg.image.shape == (512, 512, 3)


def test_bag_record_to_an_unwritable_path_is_a_clear_error(graph, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    out = graph.run("bag", "record", "camera/image", "-o", str(blocker / "x.bag"), "--count", "1")
    assert out.returncode == 1 and "cannot write bag" in out.stderr and "Not a directory" in out.stderr


def test_video_output_on_a_full_disk_stays_playable(data_dir, small_disk):
    cap = cv2.VideoCapture(str(data_dir / "video" / "s18.mp4"))
    video = VideoOutput(small_disk / "out.avi", fps=30)   # MJPG: ~100 KB a frame, fills 3 MiB fast
    with pytest.raises(OSError, match="disk full"):
        for _ in range(200):
            ok, frame = cap.read()
            assert ok
            video.write(frame)
    written = video.frames
    video.write(frame)  # later frames are dropped, not an error each
    video.close()
    assert 0 < written < 200 and video.dropped == 2
    back = cv2.VideoCapture(str(small_disk / "out.avi"))
    n = 0
    while back.read()[0]:
        n += 1
    assert n == written
    with pytest.raises(RuntimeError, match="cannot open"):
        VideoOutput("/proc/no_such_dir/out.mp4").write(frame)
