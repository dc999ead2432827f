"""Publish/subscribe over ZeroMQ, delivered as each topic's :class:`~facesculpt.runtime.qos.QoSProfile` says.

A :class:`Publisher` binds an XPUB socket (it behaves like PUB, and also tells
us how many subscribers are connected). The SUB sockets of a process are
served by a :class:`Receiver`: while the node's thread waits for messages
(inside ``Node.spin_once``) it polls them itself, so a message reaches its
callback without a thread switch; the rest of the time (callbacks running,
the node busy elsewhere) the receiver's own thread owns them and drains them as
fast as messages come. Either way each message is validated and either the
newest one is kept (``KEEP_LAST``, the default: a slow callback always gets the
freshest message and nothing piles up) or all of them in a bounded queue
(``KEEP_ALL``: for input events). Malformed messages are dropped and counted
there; the node's callbacks never see them.
"""

from __future__ import annotations

import collections
import logging
import os
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import zmq

from facesculpt.msgs import DecodeError, Message, decode
from facesculpt.paths import run_dir
from facesculpt.runtime.qos import SENSOR_DATA, QoSProfile

log = logging.getLogger("facesculpt.runtime.pubsub")

# High-water marks when the profile gives none. Small types (events, diagnostics) may queue
# deeply; big ones (images) must not pile up behind a stalled peer: memory stays bounded by
# hwm * message size.
SMALL_TYPES = {"InputEvent", "Diagnostics", "Deformation", "FaceModel", "FrameDone", "CodedFrame"}
DEFAULT_HWM_SMALL = 10000
DEFAULT_HWM_LARGE = 4
_SNDMORE, _NOBLOCK = int(zmq.SNDMORE), int(zmq.NOBLOCK)  # plain ints: IntFlag arithmetic is slow
DISCONNECT_GRACE_S = 2.0

_endpoint_counter = 0
_endpoint_lock = threading.Lock()


def new_endpoint(transport: str = "ipc", host: str = "127.0.0.1") -> str:
    """A fresh endpoint for this process: ``ipc://`` in the run dir, or ``tcp://host:*``."""
    global _endpoint_counter
    if transport == "tcp":
        return f"tcp://{host}:*"
    with _endpoint_lock:
        _endpoint_counter += 1
        n = _endpoint_counter
    return f"ipc://{run_dir()}/{os.getpid()}-{n}"


class Publisher:
    """Sends messages of one type on one topic; bound to its own endpoint.

    ``qos``: a reliable profile blocks (up to ``timeout_s``) instead of dropping when a
    subscriber's queue is full (bag playback uses it so that nothing is lost); a
    transient-local one hands each message to ``on_latch`` for the master to keep.
    """

    def __init__(self, ctx: zmq.Context, topic: str, msg_type: type[Message] | None, *,
                 qos: QoSProfile = SENSOR_DATA, endpoint: str | None = None,
                 on_latch: Callable[[str, list], None] | None = None, security=None):
        self.topic = topic
        self.on_latch = on_latch  # told of every latched message (the node forwards it to the master)
        self.msg_type = msg_type
        self.type_name = msg_type.TYPE if msg_type else "*"
        self.qos = qos
        # Read on every publish: plain attributes, not the profile's properties.
        self.latch = qos.latched
        self.reliable = reliable = qos.reliable
        self.count = 0
        self.subscribers = 0
        self.last_frames: list | None = None
        self._topic_bytes = topic.encode()
        hwm = qos.hwm
        if hwm is None:
            hwm = DEFAULT_HWM_SMALL if self.type_name in SMALL_TYPES or reliable else DEFAULT_HWM_LARGE
        self.sock = ctx.socket(zmq.XPUB)
        self.sock.setsockopt(zmq.SNDHWM, hwm)
        # A reliable publisher flushes what it queued before closing (bounded); others wait briefly.
        self.sock.setsockopt(zmq.LINGER, 30000 if reliable else 500)
        self.sock.setsockopt(zmq.XPUB_VERBOSER, 1)
        if reliable:
            self.sock.setsockopt(zmq.XPUB_NODROP, 1)
        if security is not None:
            security.server_socket(self.sock)  # CURVE server: only authorised subscribers get in
        self.sock.bind(endpoint or new_endpoint())
        self.endpoint = self.sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self._lock = threading.Lock()

    def _read_subscriptions(self) -> None:
        # Checking EVENTS first spares a raised zmq.Again on nearly every publish.
        while self.sock.get(zmq.EVENTS) & zmq.POLLIN:
            try:
                note = self.sock.recv(zmq.NOBLOCK)
            except zmq.Again:
                return
            if note[:1] == b"\x01":
                self.subscribers += 1
            elif note[:1] == b"\x00":
                self.subscribers = max(0, self.subscribers - 1)

    def subscriber_count(self) -> int:
        """Subscribers connected now (non-blocking)."""
        with self._lock:
            self._read_subscriptions()
            return self.subscribers

    def wait_for_subscribers(self, n: int = 1, timeout_s: float = 5.0) -> bool:
        """Block until ``n`` subscribers are connected (or the timeout passes)."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while True:
                self._read_subscriptions()
                if self.subscribers >= n:
                    return True
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self.sock.poll(min(50, int(remaining * 1000) + 1), zmq.POLLIN)

    def publish(self, msg: Message, timeout_s: float = 5.0) -> bool:
        """Validate and send ``msg`` (its arrays are sent without a copy: do not
        modify them afterwards). Returns False when a reliable send timed out."""
        if self.msg_type is not None and not isinstance(msg, self.msg_type):
            raise TypeError(f"{self.topic} carries {self.type_name}, not {type(msg).__name__}")
        if not msg.seq:
            msg.seq = self.count + 1
        return self.publish_frames(msg.to_frames(), timeout_s)  # validates as it encodes

    def publish_frames(self, frames: list, timeout_s: float = 5.0) -> bool:
        """Send already-encoded ``[header, *arrays]`` frames verbatim (bag playback)."""
        # Subscriptions are read by subscriber_count() (and diagnostics each second), not here:
        # a publish sits in every message's latency, where each call costs several times its
        # warm time (the thread wakes with cold caches).
        with self._lock:
            if self.reliable:
                deadline = time.monotonic() + timeout_s
                while True:
                    try:
                        self._send(frames, _NOBLOCK)
                        break
                    except zmq.Again:
                        if time.monotonic() > deadline:
                            return False
                        self.sock.poll(10, zmq.POLLOUT)
            else:
                self._send(frames, 0)
            self.count += 1
        if self.latch:
            self.last_frames = [bytes(f) for f in frames]
            if self.on_latch is not None:
                self.on_latch(self.topic, self.last_frames)
        return True

    def _send(self, frames: list, flags: int) -> None:
        # Socket.send part by part with int flags: send_multipart's type checks and IntFlag
        # arithmetic cost more than the sends. Only the first part can raise zmq.Again (a
        # multipart message is queued whole or not at all). Large arrays go without a copy.
        send = self.sock.send
        send(self._topic_bytes, flags | _SNDMORE)
        last = len(frames) - 1
        for i, frame in enumerate(frames):
            send(frame, flags | _SNDMORE if i < last else flags, copy=False)

    def close(self) -> None:
        self.sock.close()


@dataclass
class Subscription:
    """One topic a node listens to, and what the receiver thread has gathered for it."""

    topic: str
    msg_type: type[Message] | None
    callback: Callable
    qos: QoSProfile = SENSOR_DATA
    raw: bool = False  # the callback also gets the received frames (recording)
    endpoints: set = field(default_factory=set)
    queued: bool = field(init=False)  # qos.keep_all, read for every message
    # gathered by the receiver thread, taken by the node's thread (under Receiver.lock)
    latest: tuple | None = None
    pending: collections.deque = field(default_factory=lambda: collections.deque())
    received: int = 0
    dropped: int = 0
    malformed: int = 0
    last_error: str = ""
    delivered: int = 0
    last_stamp: int = 0
    last_take_age_ms: float = float("nan")
    last_key: tuple | None = None
    last_was_latched: bool = False
    publisher_lost_at: float | None = None

    def __post_init__(self):
        self.queued = self.qos.keep_all


class Receiver(threading.Thread):
    """Owns every SUB socket of a node, taking turns with the node's thread.

    The sockets belong to this thread, which drains them continuously and wakes the node's thread
    (``wakeup``), except while the node's thread waits long for messages: :meth:`take_sockets`
    (the node wants them: this thread is woken through an inproc socket and lets go),
    :meth:`receive` (the node polls and drains them itself), :meth:`return_sockets` (before the
    node runs callbacks). The hand-over costs thread switches before a message arrives rather
    than after it, which is where latency matters (benchmarks/bench_transport.py compares the
    ipc latency against raw pyzmq)."""

    def __init__(self, ctx: zmq.Context, wakeup: threading.Condition, security=None):
        super().__init__(name="facesculpt-receiver", daemon=True)
        self.ctx = ctx
        self.security = security      # facesculpt.runtime.security.Security: connect as CURVE clients
        self.lock = wakeup            # guards Subscription.latest/pending
        self.commands: queue.Queue = queue.Queue()
        self.command_posted = threading.Event()  # wakes a wait while there is no socket to poll
        self.subs: list[Subscription] = []
        self.sockets: dict[int, zmq.Socket] = {}   # id(sub) -> socket
        self.running = True
        self.disconnect_at: dict[tuple[int, str], float] = {}
        # Socket ownership: whoever holds ``own`` may use the sockets.
        self.own = threading.Lock()
        # Held by the node's thread from the moment it wants the sockets until it gives them back:
        # this thread waits on it. Plain locks and a flag, no Event: giving the sockets back sits
        # between a message's arrival and its callback, where every Python-level call shows.
        self.node_gate = threading.Lock()
        self.node_wants = False                 # the node's thread wants (or has) the sockets
        self.node_has_sockets = False
        self.poller = zmq.Poller()              # the SUB sockets (polled by the node's thread)
        self.drain_poller = zmq.Poller()        # the SUB sockets and the yield socket (this thread)
        address = f"inproc://facesculpt-receiver-yield-{id(self)}"
        self.yield_in = ctx.socket(zmq.PAIR)    # this thread's end
        self.yield_in.setsockopt(zmq.LINGER, 0)
        self.yield_in.bind(address)
        self.yield_out = ctx.socket(zmq.PAIR)   # the node's end: "let go of the sockets"
        self.yield_out.setsockopt(zmq.LINGER, 0)
        self.yield_out.connect(address)
        self.drain_poller.register(self.yield_in, zmq.POLLIN)
        self.closed = False

    # -- called from other threads --------------------------------------------------
    def add(self, sub: Subscription) -> None:
        self.commands.put(("add", sub, None))
        self.command_posted.set()

    def set_endpoints(self, sub: Subscription, endpoints: set) -> None:
        self.commands.put(("endpoints", sub, set(endpoints)))
        self.command_posted.set()

    def inject(self, sub: Subscription, frames: list) -> None:
        """Deliver frames that did not come through the socket (latched messages from the master)."""
        self.commands.put(("inject", sub, frames))
        self.command_posted.set()

    def stop(self) -> None:
        self.running = False

    # -- the node's thread ----------------------------------------------------------------
    def take_sockets(self) -> None:
        """Take the sockets from the receiver thread (it lets go within microseconds)."""
        if self.node_has_sockets:
            return
        self.node_gate.acquire()
        self.node_wants = True
        try:
            self.yield_out.send(b"", zmq.NOBLOCK)
        except zmq.ZMQError:  # a full pipe already holds a wake-up
            pass
        self.own.acquire()
        self.node_has_sockets = True

    def return_sockets(self) -> None:
        """Give the sockets back to the receiver thread, which drains them until the next take."""
        if not self.node_has_sockets:
            return
        self.node_has_sockets = False
        self.node_wants = False
        self.own.release()
        self.node_gate.release()

    def receive(self, timeout_s: float) -> bool:
        """Apply pending commands, wait up to ``timeout_s`` for messages and deliver them into the
        subscriptions (0: only what has arrived). Call between :meth:`take_sockets` and
        :meth:`return_sockets`. Returns whether anything was delivered."""
        self._apply()
        if self.disconnect_at:
            self._disconnect_due()
        if not self.sockets:
            # zmq_poll returns at once with nothing to poll: wait for a command instead.
            if timeout_s > 0 and self.command_posted.wait(timeout_s):
                self.command_posted.clear()  # the next receive() applies what was posted, in order
            return False
        try:
            ready = dict(self.poller.poll(max(0, int(timeout_s * 1000))))
        except zmq.ZMQError:  # interrupted, or the context is closing
            return False
        return self._drain(ready)

    # -- whoever owns the sockets -------------------------------------------------------------
    def _apply(self) -> None:
        while True:
            try:
                op, sub, arg = self.commands.get_nowait()
            except queue.Empty:
                return
            if op == "add":
                sock = self.ctx.socket(zmq.SUB)
                sock.setsockopt(zmq.LINGER, 0)
                if self.security is not None:
                    # CURVE client: a publisher that cannot prove the graph's key is never heard.
                    self.security.client_socket(sock)
                hwm = sub.qos.hwm
                if hwm is None:
                    hwm = sub.qos.depth if sub.queued else DEFAULT_HWM_LARGE
                sock.setsockopt(zmq.RCVHWM, hwm)
                # Exact-topic filter: zmq matches prefixes, so we also check the topic frame.
                sock.setsockopt(zmq.SUBSCRIBE, sub.topic.encode())
                self.subs.append(sub)
                self.sockets[id(sub)] = sock
                self.poller.register(sock, zmq.POLLIN)
                self.drain_poller.register(sock, zmq.POLLIN)
            elif op == "endpoints":
                sock = self.sockets[id(sub)]
                for ep in sub.endpoints - arg:
                    # Disconnecting drops what is still in the pipe: give a publisher that
                    # just left DISCONNECT_GRACE_S to deliver its last messages.
                    self.disconnect_at[(id(sub), ep)] = time.monotonic() + DISCONNECT_GRACE_S
                for ep in arg - sub.endpoints:
                    if self.disconnect_at.pop((id(sub), ep), None) is None:
                        sock.connect(ep)
                if sub.endpoints and not arg:
                    sub.publisher_lost_at = time.monotonic()
                elif arg:
                    sub.publisher_lost_at = None
                sub.endpoints = arg
            elif op == "inject":
                self._deliver(sub, arg, latched=True)

    def _disconnect_due(self) -> None:
        now = time.monotonic()
        for key, due in list(self.disconnect_at.items()):
            if now >= due:
                del self.disconnect_at[key]
                sub_id, ep = key
                try:
                    self.sockets[sub_id].disconnect(ep)
                except (zmq.ZMQError, KeyError):
                    pass

    def _drain(self, ready: dict) -> bool:
        """Receive everything pending on the ready sockets, so a latest-only subscription ends on
        the newest message. Returns whether anything was delivered."""
        delivered = False
        for sub in self.subs:
            sock = self.sockets[id(sub)]
            if sock not in ready:
                continue
            # The poll said a message waits; after it EVENTS says whether another does (no raised
            # zmq.Again after the last one).
            for n in range(100000):
                if n and not sock.get(zmq.EVENTS) & zmq.POLLIN:
                    break
                try:
                    frames = sock.recv_multipart(zmq.NOBLOCK, copy=False)
                except zmq.Again:
                    break
                delivered |= self._deliver(sub, frames)
        return delivered

    def _deliver(self, sub: Subscription, frames: list, latched: bool = False) -> bool:
        try:
            topic, msg = decode(frames, sub.msg_type)
            if topic != sub.topic:
                return False  # a longer topic sharing our prefix
        except DecodeError as exc:
            with self.lock:
                sub.malformed += 1
                sub.last_error = str(exc)
            return False
        key = (msg.stamp, msg.seq, msg.TYPE)
        with self.lock:
            if key == sub.last_key and (latched or sub.last_was_latched):
                return False  # the same latched message by both routes (master and publisher)
            sub.last_key, sub.last_was_latched = key, latched
            sub.received += 1
            item = (msg, frames[1:]) if sub.raw else (msg, None)
            if sub.queued:
                if len(sub.pending) >= sub.qos.depth:
                    sub.pending.popleft()
                    sub.dropped += 1
                sub.pending.append(item)
            else:
                if sub.latest is not None:
                    sub.dropped += 1
                sub.latest = item
        return True

    def close_sockets(self) -> None:
        """Close every socket (idempotent); the thread does it when it stops."""
        if self.closed:
            return
        self.closed = True
        for sock in [*self.sockets.values(), self.yield_in, self.yield_out]:
            sock.close(0)

    # -- the thread -----------------------------------------------------------------------
    def run(self) -> None:
        while self.running:
            if self.node_wants:  # the node's thread polls: wait until it gives them back
                if self.node_gate.acquire(timeout=0.05):
                    self.node_gate.release()
                continue
            with self.own:
                while self.running and not self.node_wants:
                    self._apply()
                    if self.disconnect_at:
                        self._disconnect_due()
                    try:
                        ready = dict(self.drain_poller.poll(50))
                    except zmq.ZMQError:
                        self.running = False
                        break
                    if self.yield_in in ready:
                        while True:
                            try:
                                self.yield_in.recv(zmq.NOBLOCK)
                            except zmq.Again:
                                break
                    if self._drain(ready):
                        with self.lock:  # a node thread waiting out a short wait takes it at once
                            self.lock.notify_all()
        with self.own:
            self.close_sockets()
