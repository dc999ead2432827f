"""Pub/sub between real processes: latest-only delivery to a slow consumer, and fuzzing."""

from __future__ import annotations

import json
import random
import time

import msgpack
import numpy as np
import pytest

from facesculpt.msgs import Diagnostics, InputEvent, encode
from facesculpt.runtime.node import Node

NODES = "tests/graph_nodes.py"


@pytest.mark.timing
@pytest.mark.slow
def test_slow_consumer_gets_fresh_messages_and_publisher_keeps_its_rate(graph, tmp_path):
    """100 Hz of 856x480x3 images into a subscriber that sleeps 100 ms per message."""
    rate_hz, count = 100.0, 2000
    period_ms = 1000.0 / rate_hz
    sub_out, pub_out = tmp_path / "sub.json", tmp_path / "pub.json"
    sub = graph.spawn("run", f"{NODES}:SlowSubscriber", f"out={sub_out}", "sleep_s=0.1")
    time.sleep(1.0)
    pub = graph.spawn("run", f"{NODES}:ImagePublisher", f"out={pub_out}", f"rate_hz={rate_hz}", f"count={count}")
    assert pub.wait(count / rate_hz + 30) == 0
    sub.terminate()
    assert sub.wait(10) == 0
    published, received = json.loads(pub_out.read_text()), json.loads(sub_out.read_text())

    # The publisher is not slowed down: its achieved rate stays within 5 % of the target.
    sent_at = np.array(published["sent_at"], dtype=np.int64)  # time_ns of each send, seq = index + 1
    achieved = (len(sent_at) - 1) / ((sent_at[-1] - sent_at[0]) / 1e9)
    assert published["sent"] == count
    assert achieved >= 0.95 * rate_hz, f"publisher fell to {achieved:.1f} Hz"

    # "At most one publish period old": no message taken was superseded by one published more than a
    # period before the take (a newer one may still be crossing the socket: 1.2 MB takes ms under load).
    taken_at = np.array(received["taken_at"][1:], dtype=np.int64)
    seqs = np.array(received["seqs"][1:])
    assert len(seqs) >= 0.8 * (count / rate_hz) / 0.1
    transit_ns = int(period_ms * 1e6)
    newest_sent = np.searchsorted(sent_at, taken_at - transit_ns, side="right")  # seq of the newest sent by then
    stale = newest_sent - seqs
    ages = np.array(received["ages_ms"][1:])
    # A receiver thread the OS does not schedule cannot drain: on a machine starved by other work
    # (measured: 0 % stale alone, 3 % at load 2.3 on 2 cores) a take can be late. Allow 5 %.
    assert np.mean(stale > 0) <= 0.05, (f"{np.sum(stale > 0)} of {len(stale)} takes were behind by up to "
                                        f"{stale.max()} messages; ages p50 {np.median(ages):.1f} ms, "
                                        f"max {ages.max():.1f} ms")
    assert np.median(ages) <= period_ms
    # ... and sequence numbers jump ahead by ~10 per take: nothing piles up.
    assert np.median(np.diff(seqs)) >= 8

    # Memory is flat over the 2000 messages (after warm-up), in both processes.
    for name, rss in (("publisher", published["rss"]), ("subscriber", received["rss"])):
        rss = np.array(rss) / 2**20
        growth = rss[-1] - rss[len(rss) // 4]
        assert growth < 16, f"{name} RSS grew {growth:.1f} MiB"


def _malformed(rng: random.Random, valid: list) -> list:
    """One malformed message body (after the topic frame), of a randomly chosen kind."""
    header = msgpack.unpackb(valid[0], raw=False)

    def with_header(**changes):
        h = json.loads(json.dumps(header))
        h.update(changes)
        return msgpack.packb(h)

    kind = rng.randrange(12)
    if kind == 0:
        return [rng.randbytes(rng.randrange(0, 64))]                       # random bytes
    if kind == 1:
        return []                                                           # topic frame alone
    if kind == 2:
        return valid + [b"extra"]                                           # wrong frame count
    if kind == 3:
        return [with_header(a=[["vector", "<f8", [3]]]), b"\0" * 24]        # wrong dtype
    if kind == 4:
        return [with_header(a=[["vector", "<f4", [4]]]), b"\0" * 16]        # wrong shape
    if kind == 5:
        return [valid[0], valid[1][:-rng.randrange(1, 12)]]                  # truncated array
    if kind == 6:
        return [with_header(a=[["vector", "<f4", [2**31 - 1]]]), b"\0" * 12]  # huge declared size
    if kind == 7:
        return [with_header(type="Image")] + valid[1:]                      # wrong type for the topic
    if kind == 8:
        return [with_header(f=dict(header["f"], kind="explode"))] + valid[1:]  # invalid field value
    if kind == 9:
        return [msgpack.packb([1, 2, 3])] + valid[1:]                        # header not a map
    if kind == 10:
        return [with_header(f=dict(header["f"], x="left"))] + valid[1:]      # wrong scalar type
    return [valid[0][: rng.randrange(1, len(valid[0]))]] + valid[1:]        # truncated header


@pytest.mark.slow
def test_fuzzed_subscriber_counts_malformed_and_delivers_valid(graph):
    """10,000 malformed multipart messages interleaved with valid ones into a subscriber process."""
    counter = graph.spawn("run", f"{NODES}:EventCounter")
    fuzzer = graph.node(Node(name="fuzzer"))
    pub = fuzzer.advertise("input/events", InputEvent)
    diags: dict = {}
    fuzzer.subscribe("diagnostics", Diagnostics, lambda m: diags.__setitem__(m.node, m.values))
    assert pub.wait_for_subscribers(1, 15), "the subscriber never connected"

    rng = random.Random(7)
    n_bad, n_good = 10000, 0
    topic = b"input/events"
    for i in range(n_bad):
        if i % 10 == 0:
            n_good += 1
            event = InputEvent(stamp=time.time_ns(), kind="drag", x=float(i), y=2.0, vector=np.ones(3, np.float32),
                               handle=-1 if i == n_bad - 10 else 0)
            pub.sock.send_multipart(encode(event, "input/events"))
        valid = encode(InputEvent(kind="move", vector=np.zeros(3, np.float32)), "input/events")[1:]
        pub.sock.send_multipart([topic] + _malformed(rng, valid))

    def done():
        v = diags.get("event_counter")
        return v is not None and v["counters"].get("valid", 0) >= n_good and v["malformed"]["input/events"] >= n_bad
    graph.spin_until(fuzzer, done, timeout=30)
    values = diags["event_counter"]
    assert counter.poll() is None, "the subscriber died"
    assert values["malformed"]["input/events"] == n_bad
    assert values["counters"]["valid"] == n_good
    assert values["counters"]["sentinel"] == 1
    assert values["errors"] == 0
