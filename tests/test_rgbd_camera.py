"""Depth cameras (issue 49), the graph's part: the camera message carries an optional aligned
depth image (uint16 mm, its own intrinsics, depth-to-colour transform) that old messages lack,
bags record and replay it (losslessly, also compressed), and the camera node reads it from a
folder of colour + 16-bit depth PNGs or a recorded bag; a missing RealSense library is one sentence."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import cv2
import msgpack
import numpy as np
import pytest
from conftest import free_port

from facesculpt.msgs import DecodeError, Image, decode, encode
from facesculpt.nodes.camera.bag_source import BagImageSource
from facesculpt.nodes.camera.rgbd_sources import RGBDFolderSource, RGBDFrame, resized_intrinsics, write_rgbd_folder
from facesculpt.nodes.camera.source_opening import open_source
from facesculpt.nodes.camera.sources import SourceError, resize_frame
from facesculpt.runtime.bag import BagReader, BagWriter
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import EXIT_BAD_PARAMETER
from facesculpt.runtime.qos import EVERY_MESSAGE

K = np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
DEPTH_K = np.array([[380.0, 0, 159.5], [0, 380.0, 119.5], [0, 0, 1]])
T = np.eye(4)
T[0, 3] = -15.0  # a depth camera 15 mm beside the colour one


def _depth(seed: int, shape=(240, 320)) -> np.ndarray:
    d = np.random.default_rng(seed).integers(400, 1500, shape).astype(np.uint16)
    d[:10] = 0  # holes
    return d


def _rgbd_image(seed: int = 0, **kw) -> Image:
    rng = np.random.default_rng(seed)
    fields = dict(stamp=5, seq=seed, frame_id="camera", image=rng.integers(0, 255, (48, 64, 3), np.uint8), K=K,
                  depth=_depth(seed), depth_K=DEPTH_K, depth_to_color=T)
    fields.update(kw)
    return Image(**fields)


def test_an_rgbd_image_round_trips_and_an_old_one_still_decodes():
    msg = _rgbd_image()
    _, back = decode(encode(msg, "camera/image"), Image)
    assert np.array_equal(back.depth, msg.depth) and back.depth.dtype == np.uint16
    assert np.array_equal(back.depth_K, DEPTH_K) and np.array_equal(back.depth_to_color, T)
    # a frame written before depth existed: its header names no depth arrays
    old = [b"camera/image", msgpack.packb({"type": "Image", "v": 1, "f": {"stamp": 1, "seq": 1, "frame_id": "c",
                                                                          "halvings": 0, "frame_size": [0, 0]},
                                           "a": [["image", "|u1", [2, 2, 3]], ["K", "<f8", [3, 3]]]}),
           bytes(12), K.tobytes()]
    _, plain = decode(old, Image)
    assert plain.depth is None and plain.depth_K is None and plain.depth_to_color is None


@pytest.mark.parametrize("change, match", [
    (dict(depth=np.zeros((4, 4), np.float32)), "depth: dtype float32"),
    (dict(depth_K=None), "needs its intrinsics depth_K"),
    (dict(depth_K=np.zeros((3, 3))), "focal lengths must be finite and positive"),
    (dict(depth_to_color=np.diag([2.0, 1, 1, 1])), "must be a rigid transform"),
    (dict(depth=None), "without a depth image"),
])
def test_bad_depth_fields_are_refused(change, match):
    with pytest.raises(DecodeError, match=match):
        _rgbd_image(**change).validate()


@pytest.mark.parametrize("compression", ["none", "png", "jpeg"])
def test_a_bag_records_and_replays_the_depth_losslessly(tmp_path, compression):
    bag = tmp_path / "rgbd.mcap"
    sent = [_rgbd_image(i) for i in range(3)]
    with BagWriter(bag, compression=compression) as w:
        for i, msg in enumerate(sent):
            w.write(1000 + i, "camera/image", msg.to_frames())
    got = [decode([r.topic.encode()] + r.frames, Image)[1] for r in BagReader(bag)]
    assert [np.array_equal(a.depth, b.depth) for a, b in zip(sent, got)] == [True] * 3
    frames = [f for f, _ in BagImageSource(str(bag), restamp=False).frames()]
    assert all(isinstance(f, RGBDFrame) for f in frames)
    assert np.array_equal(frames[1].depth, sent[1].depth) and np.array_equal(frames[1].depth_K, DEPTH_K)
    assert np.array_equal(frames[1].K, K) and np.array_equal(frames[1].depth_to_color, T)


def test_a_bag_written_with_the_depth_as_a_16_bit_png_still_replays():
    """Bags written before the depth stayed raw hold it as a 16-bit PNG frame (codec 3)."""
    import struct

    from facesculpt.runtime.bag_frames import CODEC_PNG16, CODEC_RAW, encode_depth, unpack_frames

    msg = _rgbd_image(4)
    frames = msg.to_frames()
    header = msgpack.unpackb(frames[0], raw=False)
    at = 1 + [a[0] for a in header["a"]].index("depth")
    parts = [struct.pack("<H", len(frames))]
    for i, frame in enumerate(frames):
        kind, data = (CODEC_PNG16, encode_depth(bytes(frame), msg.depth.shape)) if i == at else (CODEC_RAW, bytes(frame))
        parts += [struct.pack("<BI", kind, len(data)), data]
    _, back = decode([b"camera/image"] + unpack_frames(b"".join(parts)), Image)
    assert np.array_equal(back.depth, msg.depth) and back.depth.dtype == np.uint16


def test_a_folder_of_colour_and_depth_pngs(tmp_path):
    colours = [np.full((48, 64, 3), 20 * i, np.uint8) for i in range(3)]
    write_rgbd_folder(tmp_path / "set", [(c, _depth(i, (48, 64))) for i, c in enumerate(colours)], K=K, fps=15)
    source = open_source(str(tmp_path / "set"))
    assert isinstance(source, RGBDFolderSource) and source.native_fps == 15
    frames = [f for f, _ in source.frames()]
    assert len(frames) == 3 and np.array_equal(frames[2].color, colours[2])
    assert np.array_equal(frames[1].depth, _depth(1, (48, 64))) and np.array_equal(frames[0].K, K)
    assert frames[0].depth_K is None   # no depth_K: aligned to the colour
    # TUM's layout: depth in 1/5000 m (0.2 mm per unit), flat NAME_rgb.png / NAME_depth.png pairs
    flat = tmp_path / "flat"
    flat.mkdir()
    cv2.imwrite(str(flat / "a_rgb.png"), colours[0])
    cv2.imwrite(str(flat / "a_depth.png"), np.full((48, 64), 2500, np.uint16))
    (flat / "camera.json").write_text('{"depth_scale_mm": 0.2}')
    (frame, _), = RGBDFolderSource(flat).frames()
    assert (frame.depth == 500).all()


def test_a_folder_that_is_not_rgbd_is_one_sentence(tmp_path):
    (tmp_path / "color").mkdir()
    (tmp_path / "depth").mkdir()
    cv2.imwrite(str(tmp_path / "color" / "0.png"), np.zeros((8, 8, 3), np.uint8))
    cv2.imwrite(str(tmp_path / "depth" / "0.png"), np.zeros((8, 8), np.uint8))  # 8-bit: no depth
    with pytest.raises(SourceError, match=r"depth image .*0.png is not a single-channel 16-bit PNG"):
        next(RGBDFolderSource(tmp_path).frames())
    with pytest.raises(SourceError, match="holds no colour \\+ depth pairs"):
        RGBDFolderSource(tmp_path / "color")


def test_resized_intrinsics_follow_the_frame():
    frame = np.zeros((480, 640, 3), np.uint8)
    for mode, (w, h) in (("fit", (320, 0)), ("fill", (240, 240)), ("stretch", (320, 100))):
        K2 = resized_intrinsics(K, (640, 480), w, h, mode)
        out = resize_frame(frame, w, h, mode)
        # the principal point stays the image centre (K's is the centre of the 640x480 frame)
        assert np.allclose(K2[:2, 2], [(out.shape[1] - 1) / 2, (out.shape[0] - 1) / 2]), (mode, K2)


def test_a_missing_realsense_library_is_one_sentence(tmp_path):
    try:
        import pyrealsense2  # noqa: F401
        pytest.skip("pyrealsense2 is installed")
    except ImportError:
        pass
    env = dict(os.environ, FACESCULPT_MASTER=f"tcp://127.0.0.1:{free_port()}",
               FACESCULPT_RUN_DIR=str(tmp_path / "run"))
    result = subprocess.run([sys.executable, "-m", "facesculpt.cli", "run", "camera", "source=realsense"],
                            env=env, cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert result.returncode == EXIT_BAD_PARAMETER, result.stderr
    assert result.stderr.strip().splitlines()[-1] == (
        "facesculpt: camera: reading a RealSense camera needs the pyrealsense2 package "
        "(pip install pyrealsense2), which is not installed")


def test_the_camera_node_publishes_the_folders_depth(graph, tmp_path):
    colours = [np.full((48, 64, 3), 40 * i, np.uint8) for i in range(3)]
    write_rgbd_folder(tmp_path / "set", [(c, _depth(i, (24, 32))) for i, c in enumerate(colours)],
                      K=K, depth_K=DEPTH_K, depth_to_color=T)
    got: list[Image] = []
    listener = graph.node(Node(name="listener"))
    listener.subscribe("camera/image", Image, callback=got.append, qos=EVERY_MESSAGE)
    cam = graph.spawn("run", "camera", f"source={tmp_path / 'set'}", "fps=20", "width=32", "wait_subscribers=1",
                      "pace_by=")
    deadline = time.monotonic() + 30
    while (cam.poll() is None or len(got) < 3) and time.monotonic() < deadline:
        listener.spin_once(0.02)
    assert [m.image.shape for m in got] == [(24, 32, 3)] * 3
    assert np.array_equal(got[2].depth, _depth(2, (24, 32)))
    assert np.array_equal(got[0].depth_K, DEPTH_K) and np.array_equal(got[0].depth_to_color, T)
    assert np.allclose(got[0].K, resized_intrinsics(K, (64, 48), 32, 0, "fit"))  # the folder's K, halved
