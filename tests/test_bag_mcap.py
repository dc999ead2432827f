"""Bags are MCAP: read by the `mcap` library on its own, bags of other tools read by `bag info`,
the index used for seeking, the older format still played, a killed recorder's file readable."""

from __future__ import annotations

import json
import signal
import struct
import subprocess
import time

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from test_bag import _Collector

from facesculpt.msgs import Diagnostics, Image, InputEvent, decode
from facesculpt.runtime.bag import BagError, BagReader, BagWriter, bag_info
from facesculpt.runtime.bag_legacy import LegacyBagWriter


def _frames_of(data: bytes) -> list[bytes]:
    """The facesculpt-frames encoding undone by hand (raw frames only), as a foreign reader would."""
    (n,) = struct.unpack_from("<H", data, 0)
    pos, out = 2, []
    for _ in range(n):
        codec, length = struct.unpack_from("<BI", data, pos)
        assert codec == 0
        out.append(data[pos + 5:pos + 5 + length])
        pos += 5 + length
    assert pos == len(data)
    return out


def _messages(n=40):
    rng = np.random.default_rng(1)
    out = []
    for i in range(n):
        t = 1_700_000_000_000_000_000 + i * 50_000_000
        out.append((t + 3_000_000, "camera/image",
                    Image(stamp=t, seq=i, frame_id="cam", image=rng.integers(0, 255, (48, 64, 3), np.uint8))))
        if i % 10 == 0:
            out.append((t + 4_000_000, "input/events", InputEvent(stamp=t, seq=i, kind="press", landmark="chin")))
            out.append((t + 5_000_000, "diagnostics", Diagnostics(stamp=t, node="cam", values={"rate_hz": 20.0})))
    return out


def test_a_project_bag_is_read_by_the_mcap_library_on_its_own(tmp_path):
    bag = tmp_path / "x.mcap"
    written = _messages()
    with BagWriter(bag, chunk_bytes=64_000) as w:
        for t, topic, msg in written:
            w.write(t, topic, msg.to_frames())
    with open(bag, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().library == "facesculpt"
        summary = reader.get_summary()
        channels = {c.topic: c for c in summary.channels.values()}
        assert set(channels) == {"camera/image", "input/events", "diagnostics"}
        for topic, typ in (("camera/image", "Image"), ("input/events", "InputEvent"), ("diagnostics", "Diagnostics")):
            schema = summary.schemas[channels[topic].schema_id]
            assert channels[topic].message_encoding == "facesculpt-frames"
            assert (schema.name, schema.encoding) == (f"facesculpt.msgs.{typ}", "facesculpt-msgpack")
            assert json.loads(schema.data)["type"] == typ
        spec = json.loads(summary.schemas[channels["camera/image"].schema_id].data)
        assert spec["arrays"]["image"] == {"dtype": "|u1", "shape": ["H", "W", 3], "optional": False}
        stats = summary.statistics
        assert stats.message_count == len(written) == 48
        assert (stats.message_start_time, stats.message_end_time) == (written[0][0], written[-1][0])
        assert len(summary.chunk_indexes) >= 3 and {c.compression for c in summary.chunk_indexes} == {"lz4"}
        got = list(reader.iter_messages(log_time_order=False))
    assert len(got) == len(written)
    for (_schema, channel, message), (t, topic, msg) in zip(got, written):
        assert (channel.topic, message.log_time, message.publish_time, message.sequence) == (topic, t, msg.stamp, msg.seq)
        frames = _frames_of(message.data)
        assert frames == [bytes(f) for f in msg.to_frames()]          # our wire frames, byte for byte
        _, back = decode([topic.encode()] + frames)
        assert type(back) is type(msg) and back.stamp == msg.stamp


def _foreign_bag(path, summary=True):
    """An MCAP written by the mcap library directly: a JSON channel of another tool, and one
    channel of facesculpt frames (a foreign tool can write our encoding too)."""
    with open(path, "wb") as f:
        w = Writer(f, use_statistics=summary, repeat_channels=summary, repeat_schemas=summary,
                   use_summary_offsets=summary)
        w.start(profile="", library="some-other-tool")
        pose = w.register_channel("robot/pose", "json", w.register_schema(
            "Pose", "jsonschema", json.dumps({"type": "object"}).encode()))
        ours = w.register_channel("camera/image", "facesculpt-frames", w.register_schema(
            "facesculpt.msgs.Image", "facesculpt-msgpack", b"{}"))
        for i in range(5):
            w.add_message(pose, log_time=1000 + i, publish_time=1000 + i, data=json.dumps({"x": i}).encode())
        frames = Image(stamp=7, image=np.zeros((4, 4, 3), np.uint8)).to_frames()
        payload = struct.pack("<H", len(frames)) + b"".join(struct.pack("<BI", 0, len(f)) + bytes(f) for f in frames)
        w.add_message(ours, log_time=2000, publish_time=7, data=payload)
        w.finish()


@pytest.mark.parametrize("summary", [True, False], ids=["with-summary", "without-summary"])
@pytest.mark.slow
def test_bag_info_reads_another_tools_mcap_and_says_what_it_cannot_decode(graph, tmp_path, summary):
    bag = tmp_path / "foreign.mcap"
    _foreign_bag(bag, summary)
    out = graph.run("bag", "info", str(bag), "--json")
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout)
    assert info["records"] == 6 and info["ignored_bytes"] == 0
    assert info["topics"] == {"camera/image": {"count": 1, "types": ["Image"]},
                              "robot/pose": {"count": 5, "types": ["Pose"]}}
    sentence = info["undecodable"]
    assert sentence.count(".") == 1 and sentence.endswith(".")
    assert "5 messages on 1 channel" in sentence and "robot/pose (json, schema 'Pose' (jsonschema))" in sentence
    text = graph.run("bag", "info", str(bag)).stdout
    assert [line for line in text.splitlines() if line.startswith("note:")] == [f"note:      {sentence}"]
    reader = BagReader(bag)
    (rec,) = list(reader)                                       # ours decodes, theirs is skipped and counted
    assert rec.topic == "camera/image" and decode([b"camera/image"] + rec.frames)[1].stamp == 7
    assert reader.foreign == {"robot/pose": 5}


def test_seeking_and_info_use_the_index_not_the_chunks(tmp_path):
    """The first chunk is garbled on disk: `info` (the summary) and reading from a later time (the
    chunk index) never touch it, so both still work; reading from the start meets it and says so."""
    bag = tmp_path / "seek.mcap"
    written = _messages()
    with BagWriter(bag, chunk_bytes=20_000) as w:
        for t, topic, msg in written:
            w.write(t, topic, msg.to_frames())
    with open(bag, "rb") as f:
        chunks = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) >= 5
    data = bytearray(bag.read_bytes())
    first = chunks[0]
    for i in range(first.chunk_start_offset + first.chunk_length - 200, first.chunk_start_offset + first.chunk_length):
        data[i] ^= 0xFF
    bag.write_bytes(bytes(data))

    info = bag_info(bag)
    assert info["indexed"] and info["records"] == len(written)
    start = chunks[2].message_start_time
    later = list(BagReader(bag).messages(start_ns=start, topics=["camera/image"]))
    expected = [(t, msg) for t, topic, msg in written if t >= start and topic == "camera/image"]
    assert len(later) == len(expected) > 10
    for rec, (t, msg) in zip(later, expected):
        assert rec.time_ns == t and rec.frames == [bytes(f) for f in msg.to_frames()]
    with pytest.raises(BagError, match="does not decode"):
        list(BagReader(bag))


@pytest.mark.slow
def test_an_old_format_bag_still_plays_byte_identically(graph, data_dir, tmp_path):
    bag = tmp_path / "old.bag"
    cap = cv2.VideoCapture(str(data_dir / "video" / "d0.mp4"))
    written = []
    with LegacyBagWriter(bag) as w:
        for i in range(30):
            ok, frame = cap.read()
            assert ok
            frames = [bytes(f) for f in Image(stamp=10**18 + i * 10**8, seq=i, image=frame).to_frames()]
            w.write(10**18 + i * 10**8, "camera/image", frames)
            written.append(frames)
    assert bag.read_bytes()[:8] == b"FSBAG001"
    info = json.loads(graph.run("bag", "info", str(bag), "--json").stdout)
    assert info["format"] == "facesculpt-legacy" and info["records"] == 30 and info["duration_s"] == 2.9
    received = _Collector(graph).play(graph, bag, 30)
    assert [frames for _, frames in received] == written


@pytest.mark.slow
def test_play_from_a_time_and_a_killed_recorder(graph, data_dir, tmp_path):
    """`bag record` killed with SIGKILL (no summary written) still leaves every message older than
    a chunk's age limit readable; `bag play --start S` plays from S seconds in."""
    bag = tmp_path / "killed"                                       # no suffix: .mcap is added
    rec = graph.spawn("bag", "record", "camera/image", "-o", str(bag), stderr=subprocess.PIPE)
    cam = graph.spawn("run", "camera", f"source={data_dir / 'video' / 'd0.mp4'}", "fps=20", "max_frames=40",
                      "wait_subscribers=1", "pace_by=")
    assert cam.wait(60) == 0
    time.sleep(1.5)                                                 # > chunk_s: the last chunk is on disk
    rec.send_signal(signal.SIGKILL)
    rec.wait(10)
    rec.stderr.close()
    path = tmp_path / "killed.mcap"
    info = json.loads(graph.run("bag", "info", str(path), "--json").stdout)
    assert not info["indexed"] and info["records"] == 40, info
    records = list(BagReader(path))
    assert [decode([b"camera/image"] + r.frames)[1].seq for r in records] == list(range(1, 41))

    start_s = 1.0
    expected = [r for r in records if r.time_ns >= records[0].time_ns + start_s * 1e9]
    assert 10 < len(expected) < 40
    collector = _Collector(graph)
    player = graph.spawn("bag", "play", "--fast", "--start", str(start_s), str(path))
    graph.spin_until(collector.node, lambda: len(collector.items) >= len(expected) and player.poll() is not None, 60)
    assert player.wait(10) == 0
    collector.node.spin_once(0.2)
    assert [frames for _, frames in collector.items] == [r.frames for r in expected]
