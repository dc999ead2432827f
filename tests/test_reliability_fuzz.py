"""Fuzz every message type: 10,000 malformed messages each (huge declared sizes included),
interleaved with valid ones, into a subscriber process. Nothing crashes, every malformed
message is rejected and counted, every valid one is delivered, memory stays bounded."""

from __future__ import annotations

import random

import msgpack
import numpy as np
import pytest
import zmq

from facesculpt.msgs import (
    REGISTRY,
    Deformation,
    Diagnostics,
    FaceLandmarks,
    FaceModel,
    FaceState,
    Image,
    InputEvent,
    decode,
)
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE

NODES = "tests/reliability_nodes.py"
N_BAD = 10000
ROUNDS = 4


def _valid_examples() -> dict:
    f4, i4 = np.float32, np.int32
    return {
        "Image": Image(image=np.full((8, 6, 3), 7, np.uint8)),
        "FaceLandmarks": FaceLandmarks(points=np.ones((1, 5, 3), f4), scores=np.ones(1, f4),
                                       rois=np.ones((1, 5), f4), image_size=[6, 8]),
        "FaceModel": FaceModel(model_id="m", vertices=np.ones((4, 3), f4), triangles=np.zeros((2, 3), i4),
                               landmark_names=["a", "b"], landmark_vertices=np.arange(2, dtype=i4)),
        "FaceState": FaceState(alpha=np.ones(3, f4), beta=np.ones(2, f4), vertices=np.ones((4, 3), f4),
                               projected=np.ones((4, 2), f4), image_size=[6, 8]),
        "InputEvent": InputEvent(kind="move", vector=np.ones(3, f4)),
        "Deformation": Deformation(displacement=np.ones((4, 3), f4), static=np.arange(1, dtype=i4),
                                   handles=np.arange(1, dtype=i4), roi=np.arange(2, dtype=i4)),
        "Diagnostics": Diagnostics(node="n", values={"a": 1}),
    }


def malformed(rng: random.Random, frames: list, type_name: str) -> list:
    """One malformed message body (after the topic frame) derived from the valid ``frames``."""
    header = msgpack.unpackb(frames[0], raw=False)
    arrays = header["a"]

    def hdr(**changes):
        h = msgpack.unpackb(frames[0], raw=False)
        h.update(changes)
        return msgpack.packb(h)

    def with_array(i, dtype=None, shape=None):
        a = [list(x) for x in arrays]
        a[i] = [a[i][0], dtype or a[i][1], shape if shape is not None else a[i][2]]
        return hdr(a=a)

    kinds = 16 if arrays else 9
    kind = rng.randrange(kinds)
    other = rng.choice([t for t in REGISTRY if t != type_name])
    if kind == 0:
        return [rng.randbytes(rng.randrange(0, 96))]                      # random bytes
    if kind == 1:
        return []                                                          # topic alone
    if kind == 2:
        return frames + [b"extra"]                                         # frame count
    if kind == 3:
        return [hdr(type=other)] + frames[1:]                              # another type
    if kind == 4:
        return [msgpack.packb([1, 2, 3])] + frames[1:]                      # header not a map
    if kind == 5:
        return [hdr(f=dict(header["f"], stamp="yesterday"))] + frames[1:]   # scalar of the wrong type
    if kind == 6:
        return [frames[0][: rng.randrange(1, len(frames[0]))]] + frames[1:]  # truncated header
    if kind == 7:
        return [b"\xdb\xff\xff\xff\xff" + b"x" * 16] + frames[1:]           # str32 claiming 4 GiB
    if kind == 8:
        return [frames[0]] + [b""] * 70                                     # too many frames
    i = rng.randrange(len(arrays))
    name, dtype, shape = arrays[i]
    if kind == 9:
        wrong = "<f8" if dtype != "<f8" else "<f4"
        n = int(np.prod(shape)) * np.dtype(wrong).itemsize
        return [with_array(i, dtype=wrong)] + frames[1:1 + i] + [b"\0" * n] + frames[2 + i:]  # dtype
    if kind == 10:
        return [with_array(i, shape=list(shape) + [1])] + frames[1:]          # one more dimension
    if kind == 11:
        body = bytes(frames[1 + i])
        return [frames[0]] + frames[1:1 + i] + [body[:-1] if body else b"\0"] + frames[2 + i:]  # array bytes
    if kind == 12:
        huge = [2**31 - 1] + list(shape[1:])
        return [with_array(i, shape=huge)] + frames[1:]                      # huge declared size
    if kind == 13:
        return [with_array(i, shape=[2**40] + list(shape[1:]))] + frames[1:]  # beyond any size
    if kind == 14:
        return [with_array(i, shape=[-1] + list(shape[1:]))] + frames[1:]     # negative size
    a = [list(x) for x in arrays]
    a[i][0] = "no_such_field"
    return [hdr(a=a)] + frames[1:]                                           # unknown array


def test_malformed_generator_really_is_malformed():
    rng = random.Random(3)
    for name, msg in _valid_examples().items():
        valid = [bytes(f) for f in msg.to_frames()]
        decode([b"t"] + valid, REGISTRY[name])  # the base example is valid
        for _ in range(300):
            bad = malformed(rng, valid, name)
            try:
                decode([b"t"] + bad, REGISTRY[name])
            except ValueError:
                continue
            raise AssertionError(f"{name}: a 'malformed' message decoded: {bad[:1]}")


@pytest.mark.slow
def test_fuzz_every_message_type(graph):
    counter = graph.spawn("run", f"{NODES}:AllTypesCounter")
    fuzzer = graph.node(Node(name="fuzzer"))
    diags: dict = {}
    fuzzer.subscribe("diagnostics", Diagnostics, lambda m: diags.__setitem__(m.node, m.values))
    examples = _valid_examples()
    pubs = {name: fuzzer.advertise(f"fuzz/{name}", None, qos=EVENTS) for name in examples}
    for pub in pubs.values():
        assert pub.wait_for_subscribers(1, 20), "the subscriber never connected"
    assert graph.spin_until(fuzzer, lambda: "all_types_counter" in diags, 10)
    rss_start = diags["all_types_counter"]["counters"]["rss_mib"]

    def send(pub, parts):
        while True:
            try:
                pub.sock.send_multipart(parts, zmq.NOBLOCK)
                return
            except zmq.Again:
                pub.sock.poll(10, zmq.POLLOUT)

    rng = random.Random(7)
    n_good = 0
    rss_after = []
    # Four rounds of 2,500 per type: the first ones show what buffering costs (zmq queues up to their
    # high-water marks, and freed memory is not given back); the later ones, the same load again,
    # must not add to it: memory is bounded, not growing with the number of messages.
    for rnd in range(ROUNDS):
        for name, msg in examples.items():
            topic = f"fuzz/{name}".encode()
            valid = [bytes(f) for f in msg.to_frames()]
            for i in range(N_BAD // ROUNDS):
                if i % 20 == 0:
                    n_good += 1
                    send(pubs[name], [topic] + valid)
                send(pubs[name], [topic] + malformed(rng, valid, name))
            fuzzer.spin_once(0.0)
        want = (rnd + 1) * N_BAD // ROUNDS

        def done():
            v = diags.get("all_types_counter")
            return v is not None and all(v["malformed"].get(f"fuzz/{n}", 0) >= want for n in examples) and \
                sum(c for k, c in v["counters"].items() if k.startswith("valid:")) >= n_good
        graph.spin_until(fuzzer, done, timeout=60)
        graph.spin_until(fuzzer, lambda: False, 1.5)  # one more diagnostics period
        rss_after.append(diags["all_types_counter"]["counters"]["rss_mib"])
    values = diags["all_types_counter"]
    assert counter.poll() is None, "the subscriber died"
    for name in examples:
        assert values["malformed"][f"fuzz/{name}"] == N_BAD, (name, values["malformed"])
        assert values["counters"][f"valid:{name}"] == N_BAD // 20, (name, values["counters"])
    assert values["errors"] == 0
    print(f"\nfuzz: {len(examples) * N_BAD} malformed messages rejected over {len(examples)} types, "
          f"{n_good} valid delivered; subscriber RSS {rss_start} MiB at start, {rss_after} MiB after each round")
    # Across processes the RSS also holds what zmq queued during a burst and what glibc keeps
    # after freeing it (seen: 73, 78, 90, 94 MiB in one run, 80, 84, 73, 71 in another); the
    # decode path itself is shown flat exactly in test_decode_path_holds_no_memory. A leak of even
    # 1 KiB per message would add ~70 MiB here; the bound leaves room for the allocator's noise.
    assert rss_after[-1] - rss_after[1] < 48, f"subscriber RSS kept growing: {rss_start} -> {rss_after} MiB"


ROUNDS, PER_ROUND = 4, 2000  # malformed messages of each type per round


@pytest.mark.slow
def test_decode_path_holds_no_memory():
    """The receiver's validate-and-count path keeps nothing per malformed message: 4 rounds of
    2,000 malformed messages of every type leave traced Python memory where it was (the bound is
    under one byte per message of the last three rounds: any object kept per message shows)."""
    import gc
    import threading
    import tracemalloc

    import zmq

    from facesculpt.msgs import REGISTRY
    from facesculpt.runtime.pubsub import Receiver, Subscription

    receiver = Receiver(zmq.Context(), threading.Condition())
    examples = _valid_examples()
    subs = {n: Subscription(f"fuzz/{n}", REGISTRY[m.TYPE], lambda m: None, qos=EVERY_MESSAGE)
            for n, m in examples.items()}
    rng = random.Random(11)
    tracemalloc.start()
    try:
        traced = []
        for _ in range(ROUNDS):
            for name, msg in examples.items():
                valid = [bytes(f) for f in msg.to_frames()]
                for _ in range(PER_ROUND):
                    receiver._deliver(subs[name], [f"fuzz/{name}".encode()] + malformed(rng, valid, msg.TYPE))
            gc.collect()
            traced.append(tracemalloc.get_traced_memory()[0])
    finally:
        tracemalloc.stop()
    assert sum(s.malformed for s in subs.values()) == ROUNDS * PER_ROUND * len(examples)
    assert all(not s.pending for s in subs.values())
    assert traced[-1] - traced[0] < 64 * 1024, f"traced memory grew: {traced}"
