"""Delivery profiles (facesculpt.runtime.qos): validation, the socket options each preset sets
(those the old latch/reliable/queued flags set), and delivery between nodes: latched for late
joiners, every message vs the newest only, a reliable publisher that blocks instead of dropping."""

from __future__ import annotations

import itertools
import subprocess
import sys
import time

import numpy as np
import pytest
import zmq

from facesculpt.msgs import Image, InputEvent
from facesculpt.runtime.node import Node
from facesculpt.runtime.pubsub import Publisher, Receiver, Subscription
from facesculpt.runtime.qos import (
    DEFAULT_QUEUE_DEPTH,
    EVENTS,
    EVERY_MESSAGE,
    LATCHED,
    SENSOR_DATA,
    Durability,
    History,
    QoSProfile,
    Reliability,
)


def test_profiles_are_validated():
    assert SENSOR_DATA == QoSProfile() and SENSOR_DATA.depth == 1 and not SENSOR_DATA.keep_all
    assert EVENTS.keep_all and EVENTS.reliable and EVENTS.depth == DEFAULT_QUEUE_DEPTH and not EVENTS.latched
    assert LATCHED.latched and not LATCHED.keep_all and not LATCHED.reliable
    assert EVERY_MESSAGE.keep_all and not EVERY_MESSAGE.reliable
    assert QoSProfile(history=History.KEEP_ALL, depth=5).depth == 5
    with pytest.raises(ValueError, match="KEEP_LAST keeps the newest message only"):
        QoSProfile(depth=5)
    with pytest.raises(ValueError, match="depth"):
        QoSProfile(history=History.KEEP_ALL, depth=0)
    with pytest.raises(ValueError, match="hwm"):
        QoSProfile(hwm=0)
    with pytest.raises(TypeError, match="History"):
        QoSProfile(history="keep_all")
    with pytest.raises(AttributeError):
        SENSOR_DATA.depth = 3  # frozen: a preset cannot be changed under its users


_endpoints = itertools.count()


def _publisher(ctx, msg_type, qos):
    return Publisher(ctx, "qos/test", msg_type, qos=qos, endpoint=f"inproc://qos-test-{next(_endpoints)}")


def test_presets_set_the_socket_options_of_the_old_flags():
    ctx = zmq.Context()
    try:
        # advertise(topic, Image): drop for a slow peer, shallow queue for big messages
        pub = _publisher(ctx, Image, SENSOR_DATA)
        assert (pub.sock.getsockopt(zmq.SNDHWM), pub.sock.getsockopt(zmq.LINGER)) == (4, 500)
        assert not pub.reliable and not pub.latch
        pub.close()
        # advertise(topic, InputEvent): small messages queue deeply
        pub = _publisher(ctx, InputEvent, SENSOR_DATA)
        assert pub.sock.getsockopt(zmq.SNDHWM) == 10000
        pub.close()
        # reliable=True: deep queue, flushed on close
        pub = _publisher(ctx, Image, EVENTS)
        assert (pub.sock.getsockopt(zmq.SNDHWM), pub.sock.getsockopt(zmq.LINGER)) == (10000, 30000)
        assert pub.reliable and not pub.latch
        pub.close()
        # latch=True
        pub = _publisher(ctx, Image, LATCHED)
        assert pub.latch and not pub.reliable and pub.sock.getsockopt(zmq.SNDHWM) == 4
        pub.close()
        # hwm=N
        pub = _publisher(ctx, Image, QoSProfile(hwm=7))
        assert pub.sock.getsockopt(zmq.SNDHWM) == 7
        pub.close()
        # subscriptions: latest-only keeps 4 in the socket, queued (keep all) its depth
        rx = Receiver(ctx, None)
        subs = [Subscription("a", Image, print), Subscription("b", Image, print, qos=EVERY_MESSAGE),
                Subscription("c", Image, print, qos=QoSProfile(history=History.KEEP_ALL, depth=3)),
                Subscription("d", Image, print, qos=QoSProfile(hwm=2))]
        for sub in subs:
            rx.add(sub)
        rx._apply()
        assert [rx.sockets[id(s)].getsockopt(zmq.RCVHWM) for s in subs] == [4, 10000, 3, 2]
        assert [s.queued for s in subs] == [False, True, True, False]
        rx.close_sockets()
    finally:
        ctx.destroy(linger=0)


def _spin(nodes, predicate, timeout=10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for node in nodes:
            node.spin_once(0.01)
        if predicate():
            return True
    return predicate()


def _event(i: int) -> InputEvent:
    return InputEvent(stamp=time.time_ns(), kind="move", handle=i, source="qos-test")


def test_latched_reaches_a_late_joiner_and_volatile_does_not(graph):
    pub = graph.node(Node(name="qos_pub"))
    latched = pub.advertise("qos/latched", InputEvent, qos=LATCHED)
    volatile = pub.advertise("qos/volatile", InputEvent)
    assert pub.link.connected.wait(10)
    latched.publish(_event(7))
    volatile.publish(_event(8))
    time.sleep(0.5)  # the master has stored the latched message
    late = Node(name="qos_late")
    got = {"latched": [], "volatile": []}
    late.subscribe("qos/latched", InputEvent, lambda m: got["latched"].append(m.handle))
    late.subscribe("qos/volatile", InputEvent, lambda m: got["volatile"].append(m.handle))
    graph.node(late)
    assert _spin([pub, late], lambda: got["latched"] == [7])
    _spin([pub, late], lambda: False, timeout=1.0)
    assert got == {"latched": [7], "volatile": []}


def test_keep_all_delivers_every_message_and_keep_last_the_newest(graph):
    pub = graph.node(Node(name="qos_events"))
    out = pub.advertise("qos/events", InputEvent, qos=EVENTS)
    every, newest = [], []
    sub_all = Node(name="qos_all")
    sub_all.subscribe("qos/events", InputEvent, lambda m: every.append(m.handle), qos=EVENTS)
    sub_new = Node(name="qos_newest")
    sub_new.subscribe("qos/events", InputEvent, lambda m: newest.append(m.handle))
    graph.node(sub_all), graph.node(sub_new)
    assert out.wait_for_subscribers(2, 10)
    for i in range(50):
        out.publish(_event(i))
    time.sleep(1.0)  # neither subscriber runs callbacks meanwhile: its receiver thread gathers
    assert _spin([sub_all, sub_new], lambda: len(every) == 50 and newest)
    assert every == list(range(50))
    assert newest == [49] and sub_new.subscriptions[0].dropped == 49


# A subscriber that reads nothing, in a process of its own: libzmq aborts now and then when a SUB
# socket with a full pipe in the middle of a multipart message is closed (session_base.cpp,
# "Resource temporarily unavailable"; libzmq issue 3442), so the peer is killed, never closed.
_SILENT_PEER = """
import sys, time, zmq
sock = zmq.Context().socket(zmq.SUB)
sock.setsockopt(zmq.RCVHWM, 1)
sock.setsockopt(zmq.SUBSCRIBE, b"qos/stall")
sock.connect(sys.argv[1])
time.sleep(60)
"""


def test_a_reliable_publisher_blocks_where_best_effort_drops():
    """A peer that reads nothing: RELIABLE (EVENTS, the old reliable=True) times out instead
    of dropping; BEST_EFFORT (SENSOR_DATA) returns at once, dropping."""
    # Frames under pyzmq's zero-copy threshold: destroying a context under queued zero-copy
    # frames aborted libzmq now and then; the kernel's socket buffers still fill within the sends.
    image = Image(stamp=1, image=np.zeros((100, 100, 3), np.uint8))
    # hwm 1: the publisher's queue is full as soon as the socket buffers are
    for qos, blocks in ((SENSOR_DATA, False), (QoSProfile(reliability=Reliability.RELIABLE, hwm=1), True)):
        ctx = zmq.Context()
        pub = Publisher(ctx, "qos/stall", Image, qos=qos, endpoint="tcp://127.0.0.1:*")
        peer = subprocess.Popen([sys.executable, "-c", _SILENT_PEER, pub.endpoint])
        try:
            assert pub.wait_for_subscribers(1, 20)
            sent = [pub.publish(Image(stamp=i + 1, image=image.image), timeout_s=0.2) for i in range(5000)
                    if not blocks or pub.count == i]  # a reliable send stops at its first time-out
            assert all(sent) is not blocks
        finally:
            peer.kill()
            peer.wait()
            pub.sock.setsockopt(zmq.LINGER, 0)
            pub.close()
            ctx.term()


def test_durability_and_reliability_are_independent_of_history():
    custom = QoSProfile(history=History.KEEP_ALL, depth=20, reliability=Reliability.RELIABLE,
                        durability=Durability.TRANSIENT_LOCAL, hwm=50)
    assert (custom.keep_all, custom.depth, custom.reliable, custom.latched, custom.hwm) == (True, 20, True, True, 50)
