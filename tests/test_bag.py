"""Bags (MCAP): a real video recorded through the camera node, replayed byte-identically,
and recovered record by record after being cut at random offsets."""

from __future__ import annotations

import io
import json
import random
import struct

import cv2
import numpy as np
import pytest
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Chunk
from mcap.stream_reader import breakup_chunk

from facesculpt.msgs import Image, decode, encode
from facesculpt.runtime.bag import MAGIC, BagError, BagReader, BagWriter
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVERY_MESSAGE


def _video_frames(path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            return frames
        frames.append(frame)


def _record(graph, video, bag, count, *extra):
    rec = graph.spawn("bag", "record", "camera/image", "-o", str(bag), "--count", str(count), *extra)
    cam = graph.spawn("run", "camera", f"source={video}", "fps=60", f"max_frames={count}", "wait_subscribers=1",
                       "pace_by=")  # no renderer to pace by: do not wait for one
    assert rec.wait(60) == 0
    cam.wait(10)


class _Collector:
    def __init__(self, graph):
        self.items: list = []
        self.node = graph.node(Node(name="collector"))
        self.node.subscribe("camera/image", Image, lambda m, f: self.items.append((m, [bytes(x) for x in f])),
                            qos=EVERY_MESSAGE, raw=True)

    def play(self, graph, bag, expected, timeout=60):
        import subprocess

        self.items.clear()
        player = graph.spawn("bag", "play", "--fast", str(bag), stderr=subprocess.PIPE)
        graph.spin_until(self.node, lambda: len(self.items) >= expected and player.poll() is not None, timeout)
        assert player.wait(10) == 0
        self.node.spin_once(0.2)
        if len(self.items) != expected:  # say what happened on both sides
            raise AssertionError(f"{len(self.items)} of {expected} played; player: {player.stderr.read()!r}; "
                                 f"collector: {self.node.diagnostics()}")
        player.stderr.close()
        return list(self.items)


@pytest.mark.slow
def test_bag_round_trip_of_a_real_video_is_byte_identical(graph, data_dir, tmp_path):
    video = data_dir / "video" / "d3.mp4"
    truth = _video_frames(video)
    bag = tmp_path / "d3.mcap"
    _record(graph, video, bag, len(truth))

    records = list(BagReader(bag))
    assert len(records) == len(truth) == 354
    info = json.loads(graph.run("bag", "info", str(bag), "--json").stdout)
    assert info["records"] == 354 and info["ignored_bytes"] == 0
    assert info["format"] == "mcap" and info["indexed"] and info["undecodable"] is None
    assert info["topics"]["camera/image"] == {"count": 354, "types": ["Image"]}

    received = _Collector(graph).play(graph, bag, len(records))
    assert len(received) == len(records)
    for (msg, frames), rec, frame in zip(received, records, truth):
        _, recorded = decode([b"camera/image"] + rec.frames)
        assert frames == rec.frames                      # every frame byte-identical
        assert msg.stamp == recorded.stamp and msg.seq == recorded.seq
        assert np.array_equal(msg.image, frame)          # and equal to the decoded video


def _record_ends(path) -> list[tuple[int, int]]:
    """(byte offset where each top-level MCAP record ends, messages in it), read independently
    of the project's reader: the record framing (u8 opcode, u64 length) by hand, a chunk's
    messages by the mcap library."""
    data = path.read_bytes()
    pos, ends = len(MAGIC), []
    while pos + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, pos)
        body = data[pos + 9:pos + 9 + length]
        pos += 9 + length
        if pos > len(data):
            break
        messages = 0
        if opcode == Opcode.CHUNK:
            chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
            messages = sum(type(r).__name__ == "Message" for r in breakup_chunk(chunk))
        ends.append((pos, messages))
        if opcode == Opcode.FOOTER:
            break
    return ends


@pytest.mark.slow
def test_bag_cut_at_random_offsets_recovers_every_complete_record(graph, data_dir, tmp_path):
    video = data_dir / "video" / "d0.mp4"
    truth = _video_frames(video)[:40]
    bag = tmp_path / "d0.mcap"
    _record(graph, video, bag, len(truth), "--compression", "png")
    ends = _record_ends(bag)
    assert sum(n for _, n in ends) == len(truth) and ends[-1][0] + len(MAGIC) == bag.stat().st_size
    assert sum(1 for _, n in ends if n) >= 3, "the recording should span several chunks"

    collector = _Collector(graph)
    rng = random.Random(2)
    for offset in sorted(rng.sample(range(len(MAGIC), bag.stat().st_size - 1), 12)):
        cut = tmp_path / f"cut-{offset}.mcap"
        with open(bag, "rb") as src, open(cut, "wb") as dst:
            dst.write(src.read(offset))
        complete = sum(n for e, n in ends if e <= offset)     # the messages of every whole chunk
        last_end = max([e for e, _ in ends if e <= offset], default=len(MAGIC))
        info = json.loads(graph.run("bag", "info", str(cut), "--json").stdout)
        assert info["records"] == complete and not info["indexed"]
        assert info["ignored_bytes"] == offset - last_end
        if complete == 0:
            continue
        received = collector.play(graph, cut, complete)
        assert len(received) == complete, f"cut at {offset}: {len(received)} of {complete} played"
        for (msg, _), frame in zip(received, truth):   # png is lossless: the video's pixels, exactly
            assert np.array_equal(msg.image, frame)
        cut.unlink()


def test_bag_errors_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.mcap"):
        BagReader(tmp_path / "nope.mcap")
    not_a_bag = tmp_path / "x.bag"
    not_a_bag.write_bytes(b"hello world")
    with pytest.raises(BagError, match="not a facesculpt bag"):
        BagReader(not_a_bag)
    with pytest.raises(BagError, match="cannot write bag"):
        BagWriter(tmp_path / "missing-dir" / "y.mcap")


def test_bag_jpeg_compression_is_close_and_small(tmp_path):
    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.integers(0, 255, (120, 160, 3), dtype=np.uint8), (9, 9), 3)
    frames = encode(Image(stamp=5, image=img), "camera/image")[1:]
    with BagWriter(tmp_path / "j.mcap", compression="jpeg") as w:
        w.write(1, "camera/image", frames)
    (rec,) = list(BagReader(tmp_path / "j.mcap"))
    _, msg = decode([b"camera/image"] + rec.frames)
    assert msg.stamp == 5
    assert (tmp_path / "j.mcap").stat().st_size < img.nbytes / 2
    assert np.abs(msg.image.astype(int) - img).mean() < 3
