"""The master: a small ROS-1-style registry of nodes, topics and latched messages.

One process (`facesculpt master`, or started by `facesculpt launch`) answers
requests on ``$FACESCULPT_MASTER`` (default ``tcp://127.0.0.1:11411``). Nodes
register themselves and their publishers, heartbeat, and look up the endpoints
of the topics they subscribe to; a ``generation`` number that grows with every
change of the publisher table tells them when to look again. Latched messages
(such as ``face/model``) are kept here so that a node started later still gets
them. Nodes that stop heartbeating are forgotten after ``NODE_TIMEOUT_S``.

Requests are multipart: ``[msgpack {"op": ..., ...}] [extra frames]``; replies
likewise. The master holds no socket to any node and never blocks on one.
"""

from __future__ import annotations

import logging
import os
import signal
import time

import msgpack
import zmq

DEFAULT_MASTER = "tcp://127.0.0.1:11411"
NODE_TIMEOUT_S = 5.0
log = logging.getLogger("facesculpt.runtime.master")


def master_address() -> str:
    return os.environ.get("FACESCULPT_MASTER", DEFAULT_MASTER)


class Registry:
    """The master's state and request handlers (no sockets: testable on its own)."""

    def __init__(self, clock=time.monotonic):
        self.clock = clock
        self.nodes: dict[str, dict] = {}          # name -> {pid, host, since, seen}
        self.publishers: dict[str, dict] = {}     # topic -> {node: {endpoint, type}}
        self.subscribers: dict[str, set] = {}     # topic -> {node}
        self.latched: dict[str, tuple[int, list[bytes]]] = {}  # topic -> (version, frames)
        self.generation = 0
        self.registrations = 0  # node registrations so far: grows when a node (re)starts

    # -- bookkeeping ----------------------------------------------------------
    def _touch(self, node: str) -> bool:
        info = self.nodes.get(node)
        if info is None:
            return False
        info["seen"] = self.clock()
        return True

    def _drop_node(self, node: str) -> None:
        self.nodes.pop(node, None)
        for pubs in self.publishers.values():
            if pubs.pop(node, None) is not None:
                self.generation += 1
        for subs in self.subscribers.values():
            subs.discard(node)

    def prune(self) -> list[str]:
        """Forget nodes that stopped heartbeating; returns their names."""
        now = self.clock()
        dead = [n for n, info in self.nodes.items() if now - info["seen"] > NODE_TIMEOUT_S]
        for name in dead:
            log.info("node %s stopped answering; forgetting it", name)
            self._drop_node(name)
        return dead

    # -- requests ---------------------------------------------------------------
    def handle(self, req: dict, frames: list[bytes]) -> tuple[dict, list[bytes]]:
        op = req.get("op")
        handler = getattr(self, f"op_{op}", None) if isinstance(op, str) else None
        if handler is None:
            return {"ok": False, "error": f"unknown op {op!r}"}, []
        try:
            return handler(req, frames)
        except (KeyError, TypeError, ValueError) as exc:
            return {"ok": False, "error": f"bad {op} request: {exc}"}, []

    def op_ping(self, req, frames):
        return {"ok": True, "pid": os.getpid(), "generation": self.generation}, []

    def op_register_node(self, req, frames):
        name = str(req["node"])
        if name in self.nodes:
            # A respawned node takes over its name: its old publishers are gone.
            self._drop_node(name)
        now = self.clock()
        self.nodes[name] = {"pid": int(req.get("pid", 0)), "host": str(req.get("host", "")),
                            "since": now, "seen": now}
        self.registrations += 1
        return {"ok": True, "generation": self.generation}, []

    def op_unregister_node(self, req, frames):
        name = str(req["node"])
        if self.nodes.get(name, {}).get("pid") == req.get("pid"):
            self._drop_node(name)
        return {"ok": True}, []

    def op_advertise(self, req, frames):
        node, topic = str(req["node"]), str(req["topic"])
        if not self._touch(node):
            return {"ok": False, "unknown_node": True}, []
        entry = {"endpoint": str(req["endpoint"]), "type": str(req["type"])}
        if self.publishers.setdefault(topic, {}).get(node) != entry:
            self.publishers[topic][node] = entry
            self.generation += 1
        return {"ok": True}, []

    def op_subscribe(self, req, frames):
        node, topic = str(req["node"]), str(req["topic"])
        if not self._touch(node):
            return {"ok": False, "unknown_node": True}, []
        self.subscribers.setdefault(topic, set()).add(node)
        return {"ok": True}, []

    def op_heartbeat(self, req, frames):
        known = self._touch(str(req["node"]))
        return {"ok": True, "known": known, "generation": self.generation, "registrations": self.registrations}, []

    def op_lookup(self, req, frames):
        topic = str(req["topic"])
        pubs = self.publishers.get(topic, {})
        return {"ok": True, "generation": self.generation,
                "endpoints": sorted({p["endpoint"] for p in pubs.values()}),
                "types": sorted({p["type"] for p in pubs.values()}),
                "latched_version": self.latched.get(topic, (0, None))[0]}, []

    def op_latch_set(self, req, frames):
        topic = str(req["topic"])
        version = self.latched.get(topic, (0, None))[0] + 1
        self.latched[topic] = (version, list(frames))
        self.generation += 1  # subscribers look again and fetch it
        return {"ok": True, "version": version}, []

    def op_latch_get(self, req, frames):
        version, stored = self.latched.get(str(req["topic"]), (0, []))
        return {"ok": True, "version": version}, list(stored)

    def op_nodes(self, req, frames):
        now = self.clock()
        out = []
        for name, info in sorted(self.nodes.items()):
            out.append({
                "node": name, "pid": info["pid"], "host": info["host"],
                "uptime_s": round(now - info["since"], 1), "last_seen_s": round(now - info["seen"], 1),
                "publishes": sorted(t for t, p in self.publishers.items() if name in p),
                "subscribes": sorted(t for t, s in self.subscribers.items() if name in s),
            })
        return {"ok": True, "nodes": out}, []

    def op_topics(self, req, frames):
        topics = sorted(set(self.publishers) | set(self.subscribers) | set(self.latched))
        out = []
        for topic in topics:
            pubs = self.publishers.get(topic, {})
            out.append({
                "topic": topic,
                "types": sorted({p["type"] for p in pubs.values()}),
                "publishers": sorted(pubs), "subscribers": sorted(self.subscribers.get(topic, ())),
                "latched": topic in self.latched,
            })
        return {"ok": True, "topics": out}, []


def serve(address: str | None = None, *, ready=None, stop=None, security=None) -> None:
    """Run the master until SIGINT/SIGTERM (or until ``stop`` (an Event) is set).

    With ``security`` (or ``$FACESCULPT_KEYS``) the socket is a CURVE server that only
    authorised clients reach: a stranger cannot register nodes or fake publishers."""
    from facesculpt.runtime.security import Security, check_exposure, insecure_allowed

    address = address or master_address()
    security = security if security is not None else Security.from_env()
    warning = check_exposure("the master", address, security, insecure_allowed())  # SecurityError: refused
    if warning:
        log.warning("%s", warning)
    ctx = zmq.Context.instance()
    auth = security.start_authenticator(ctx) if security else None
    sock = ctx.socket(zmq.ROUTER)
    sock.setsockopt(zmq.LINGER, 0)
    if security:
        security.server_socket(sock)
    try:
        sock.bind(address)
    except zmq.ZMQError as exc:
        raise RuntimeError(f"cannot bind the master to {address}: {exc} (is another master running?)") from None
    registry = Registry()
    running = [True]
    if stop is None:
        def _stop(signum, frame):
            running[0] = False
        signal.signal(signal.SIGINT, _stop)
        signal.signal(signal.SIGTERM, _stop)
    log.info("master listening on %s", address)
    if ready is not None:
        ready.set()
    poller = zmq.Poller()
    poller.register(sock, zmq.POLLIN)
    last_prune = time.monotonic()
    while running[0] and not (stop is not None and stop.is_set()):
        if poller.poll(200):
            while True:
                try:
                    parts = sock.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                reply = _answer(registry, parts)
                if reply is not None:
                    sock.send_multipart(reply)
        if time.monotonic() - last_prune > 1.0:
            registry.prune()
            last_prune = time.monotonic()
    sock.close(0)
    if auth is not None:
        auth.stop()


def _answer(registry: Registry, parts: list[bytes]) -> list[bytes] | None:
    # ROUTER framing from a REQ peer: [identity, b"", request, *extra]
    if len(parts) < 3 or parts[1] != b"":
        return None
    identity, body, extra = parts[0], parts[2], parts[3:]
    try:
        req = msgpack.unpackb(body, raw=False)
        if not isinstance(req, dict):
            raise ValueError("not a map")
        reply, frames = registry.handle(req, extra)
    except Exception as exc:  # a malformed request must never stop the master
        reply, frames = {"ok": False, "error": f"malformed request: {exc.__class__.__name__}"}, []
    return [identity, b"", msgpack.packb(reply, use_bin_type=True)] + frames


class MasterClient:
    """Request/reply to the master with a timeout; a lost reply recreates the socket
    (the "lazy pirate" pattern), so a dead or restarted master never wedges a node."""

    def __init__(self, address: str | None = None, timeout_s: float = 1.0, context=None, security=None):
        from facesculpt.runtime.security import Security

        self.address = address or master_address()
        # CURVE client keys: given, or from $FACESCULPT_KEYS (None: plain).
        self.security = security if security is not None else Security.from_env()
        self.timeout_ms = int(timeout_s * 1000)
        self.ctx = context or zmq.Context.instance()
        self.sock = None

    def _socket(self):
        if self.sock is None:
            self.sock = self.ctx.socket(zmq.REQ)
            self.sock.setsockopt(zmq.LINGER, 0)
            if self.security is not None:
                self.security.client_socket(self.sock)
            self.sock.connect(self.address)
        return self.sock

    def request(self, op: str, frames: list | None = None, **fields) -> tuple[dict, list[bytes]] | None:
        """Send one request; returns (reply, frames) or None when the master did not answer."""
        sock = self._socket()
        fields["op"] = op
        sock.send_multipart([msgpack.packb(fields, use_bin_type=True)] + list(frames or []))
        if sock.poll(self.timeout_ms, zmq.POLLIN):
            parts = sock.recv_multipart()
            return msgpack.unpackb(parts[0], raw=False), parts[1:]
        self.close()
        return None

    def call(self, op: str, **fields) -> dict:
        """Like :meth:`request` but raises a clear error when no master answers."""
        answer = self.request(op, **fields)
        if answer is None:
            raise RuntimeError(f"no master answers at {self.address}: start one with `facesculpt master` "
                               f"or run a graph with `facesculpt launch` (FACESCULPT_MASTER sets the address)")
        return answer[0]

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close(0)
            self.sock = None


def master_alive(address: str | None = None, timeout_s: float = 0.5, security=None) -> bool:
    client = MasterClient(address, timeout_s, security=security)
    try:
        return client.request("ping") is not None
    finally:
        client.close()
