"""`process` analyses the next frame on a second thread while it composites this one: the items
come in order, errors reach the consumer, and the output is the sequential run's, bit for bit."""

from __future__ import annotations

import argparse
import threading
import time
from pathlib import Path

import pytest

from facesculpt.app.read_ahead import ReadAhead


def test_items_in_order_and_ahead_of_the_consumer():
    made = []

    def items():
        for i in range(20):
            made.append(i)
            yield i

    with ReadAhead(items(), depth=3) as it:
        first = next(it)
        time.sleep(0.2)
        assert first == 0 and 2 <= len(made) <= 5  # a few made ahead, no more
        assert [first, *it] == list(range(20))


def test_an_error_in_the_thread_is_raised_to_the_consumer_at_its_place():
    def items():
        yield 1
        yield 2
        raise ValueError("frame 3 is broken")

    got = []
    with pytest.raises(ValueError, match="frame 3 is broken"), ReadAhead(items()) as it:
        for x in it:
            got.append(x)
    assert got == [1, 2]


def test_leaving_early_stops_the_thread():
    def endless():
        i = 0
        while True:
            yield i
            i += 1

    before = threading.active_count()
    with ReadAhead(endless(), depth=2) as it:
        assert next(it) == 0
    time.sleep(0.3)
    assert threading.active_count() == before


def test_process_with_read_ahead_writes_the_sequential_output(data_dir, models_dir, tmp_path):
    from facesculpt.app import process_command
    from facesculpt.app.process import process_file
    from facesculpt.runtime.process_limits import limit_threads

    parser = argparse.ArgumentParser()
    process_command.register(parser.add_subparsers())
    outputs = {}
    for read_ahead in (True, False):
        out = tmp_path / str(read_ahead) / "%03d.png"
        args = parser.parse_args(["process", str(data_dir / "video" / "d3.mp4"), "-o", str(out), "--edits", "chin",
                                  "--max-frames", "20", "--neutral-frames", "6", "--quiet"])
        args.read_ahead = read_ahead
        limit_threads(1)
        code, message = process_file(args, args.input[0], args.output)
        assert code == 0 and "wrote 20 frames" in message
        outputs[read_ahead] = {p.name: p.read_bytes() for p in Path(out).parent.iterdir()}
    assert len(outputs[True]) == 20 and outputs[True] == outputs[False]


def test_write_behind_writes_in_order_and_raises_the_writers_error():
    from facesculpt.app.write_behind import WriteBehind

    class Output:
        def __init__(self, fail_at=None):
            self.got, self.fail_at, self.thread = [], fail_at, None

        def write(self, frame):
            self.thread = threading.current_thread()
            if frame == self.fail_at:
                raise OSError(28, "disk full")
            time.sleep(0.005)
            self.got.append(frame)

    out = Output()
    with WriteBehind(out, depth=2) as w:
        for i in range(10):
            w.write(i)
    assert out.got == list(range(10)) and out.thread is not threading.current_thread()
    out = Output(fail_at=3)
    with pytest.raises(OSError, match="disk full"), WriteBehind(out, depth=2) as w:
        for i in range(10):
            w.write(i)
    assert out.got == [0, 1, 2]


def test_pipelined_video_is_byte_identical_to_the_sequential_one(data_dir, models_dir, tmp_path):
    """Decode + analyse | composite | encode on three threads: the same H.264 file, byte for byte."""
    from facesculpt.app import process_command
    from facesculpt.app.process import process_file
    from facesculpt.runtime.process_limits import limit_threads

    parser = argparse.ArgumentParser()
    process_command.register(parser.add_subparsers())
    outputs = {}
    for pipelined in (True, False):
        out = tmp_path / f"{pipelined}.mp4"
        args = parser.parse_args(["process", str(data_dir / "video" / "d3.mp4"), "-o", str(out), "--edits", "chin",
                                  "--max-frames", "24", "--neutral-frames", "6", "--quiet"])
        args.read_ahead = pipelined
        limit_threads(1)
        code, message = process_file(args, args.input[0], args.output)
        assert code == 0 and "wrote 24 frames" in message
        outputs[pipelined] = out.read_bytes()
    assert len(outputs[True]) > 10_000 and outputs[True] == outputs[False]
