"""The node base every process of the graph is built on.

A node declares its parameters in ``PARAMS`` (:mod:`facesculpt.runtime.parameters`:
each a ``Param`` with its description and valid range or choices, or a plain default),
and in :meth:`Node.setup` advertises topics, subscribes with callbacks (each with a
:class:`~facesculpt.runtime.qos.QoSProfile`) and starts timers. :meth:`Node.spin` then runs callbacks on
the node's own thread until SIGINT/SIGTERM. Three threads per process:

* the node's thread: your callbacks and timers, nothing else;
* the receiver (:class:`facesculpt.runtime.pubsub.Receiver`): drains SUB sockets,
  validates, keeps the newest (or queues, as the subscription's QoS says), counts drops and
  malformed input;
* the master link (:class:`MasterLink`): registers with the master,
  heartbeats, follows publishers that move, fetches latched messages. A dead
  or restarted master never blocks the node's thread.

Example (a complete custom node)::

    from facesculpt.runtime.node import Node
    from facesculpt.runtime.parameters import Param
    from facesculpt.msgs import Image

    class Brightness(Node):
        NAME = "brightness"
        PARAMS = {"gain": Param(1.5, "brightness factor", range=(0.0, 10.0))}
        def setup(self):
            self.out = self.advertise("camera/bright", Image)
            self.subscribe("camera/image", Image, self.on_image)
        def on_image(self, msg):
            img = (msg.image * self.params.gain).clip(0, 255).astype("uint8")
            self.out.publish(Image(stamp=msg.stamp, image=img, K=msg.K))

    if __name__ == "__main__":
        Brightness.main()
"""

from __future__ import annotations

import contextlib
import difflib
import importlib
import importlib.util
import json
import logging
import math
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zmq

from facesculpt.msgs import Diagnostics, Message
from facesculpt.runtime.master import MasterClient, master_address
from facesculpt.runtime.parameters import (
    EXIT_BAD_PARAMETER,
    EXIT_STOP_GRAPH,
    ParameterError,
    Params,
    declared,
    default_values,
    parse_assignments,
    resolve_params,
)
from facesculpt.runtime.process_limits import limit_threads
from facesculpt.runtime.pubsub import Publisher, Receiver, Subscription, new_endpoint
from facesculpt.runtime.qos import SENSOR_DATA, QoSProfile
from facesculpt.runtime.security import SecurityError, check_exposure, insecure_allowed
from facesculpt.runtime.stop_signals import held_signal
from facesculpt.runtime.topics import DIAGNOSTICS_TOPIC, check_declared

# One log format for every process of the graph (facesculpt.cli uses it too).
LOG_FORMAT = "%(asctime)s %(levelname).1s [%(name)s] %(message)s"


# -- the master link ----------------------------------------------------------------------
class MasterLink(threading.Thread):
    """Keeps this node registered with the master and its subscriptions connected."""
    # Heartbeat and lookup period: also how late a subscriber may notice a respawned publisher.
    PERIOD_S = 0.1

    def __init__(self, node: Node):
        super().__init__(name="facesculpt-master-link", daemon=True)
        self.node = node
        self.client = MasterClient(node.master, timeout_s=1.0, security=node.security)
        self.registered = False
        self.dirty = False          # a publisher/subscription was added while registering
        self.generation, self.registrations = -1, 0  # registrations: the master's count; grows when a node (re)starts
        self.latched_versions: dict[str, int] = {}
        self.latch_pending: dict[str, list] = {}
        self.lock = threading.Lock()
        self.wake = threading.Event()
        self.stopping = False
        self.warned = False
        self.connected = threading.Event()   # set once registered (tests and tools wait on it)

    def push_latched(self, topic: str, frames: list) -> None:
        with self.lock:
            self.latch_pending[topic] = frames
        self.wake.set()

    def _request(self, op: str, frames=None, **fields):
        answer = self.client.request(op, frames, **fields)
        if answer is None:
            if self.registered or not self.warned:
                self.node.log.warning("no master answers at %s; retrying (start one with `facesculpt master`)",
                                      self.client.address)
                self.warned = True
            self.registered = False
            self.connected.clear()
        return answer

    def invalidate(self) -> None:
        """Register again (a publisher or subscription was added); safe from any thread."""
        with self.lock:
            self.dirty = True
            self.registered = False
        self.wake.set()

    def _register(self) -> bool:
        node = self.node
        with self.lock:
            self.dirty = False
        if self._request("register_node", node=node.name, pid=os.getpid(), host=socket.gethostname()) is None:
            return False
        for pub in list(node.publishers.values()):
            self._request("advertise", node=node.name, topic=pub.topic, endpoint=pub.endpoint, type=pub.type_name)
            if pub.latch and pub.last_frames is not None:
                self.push_latched(pub.topic, pub.last_frames)
        for sub in list(node.subscriptions):
            self._request("subscribe", node=node.name, topic=sub.topic)
        with self.lock:
            if self.dirty:  # something was added meanwhile: go round again
                return False
            self.registered = True
        self.generation = -1
        self.warned = False
        self.connected.set()
        return True

    def _follow(self) -> None:
        beat = self._request("heartbeat", node=self.node.name)
        if beat is None:
            return
        reply = beat[0]
        self.registrations = int(reply.get("registrations", self.registrations))
        if not reply.get("known"):
            self.registered = False
            return
        # Publishers may appear after we register: look again while a subscription has
        # none yet, and whenever the publisher table changed.
        needs = reply["generation"] != self.generation or any(not s.endpoints for s in self.node.subscriptions)
        if not needs:
            return
        for sub in list(self.node.subscriptions):
            answer = self._request("lookup", topic=sub.topic)
            if answer is None:
                return
            info = answer[0]
            endpoints = set(info["endpoints"])
            if endpoints != sub.endpoints:
                self.node.receiver.set_endpoints(sub, endpoints)
            version = info.get("latched_version", 0)
            if version and version != self.latched_versions.get(sub.topic):
                got = self._request("latch_get", topic=sub.topic)
                if got is not None and got[1]:
                    self.latched_versions[sub.topic] = got[0]["version"]
                    self.node.receiver.inject(sub, [sub.topic.encode()] + got[1])
        self.generation = reply["generation"]

    def run(self) -> None:
        while not self.stopping:
            try:
                if not self.registered:
                    self._register()
                if self.registered:
                    with self.lock:
                        pending, self.latch_pending = self.latch_pending, {}
                    for topic, frames in pending.items():
                        self._request("latch_set", frames, topic=topic)
                    self._follow()
            except zmq.ZMQError as exc:  # context closing during shutdown
                if self.stopping:
                    break
                self.node.log.debug("master link: %s", exc)
            self.wake.wait(self.PERIOD_S)
            self.wake.clear()
        with contextlib.suppress(Exception):
            if self.registered:
                self.client.request("unregister_node", node=self.node.name, pid=os.getpid())
        self.client.close()


# -- the node -----------------------------------------------------------------------------
# Waits at least this long (s) poll the sockets on the node's thread. A hand-over of the sockets
# costs two thread switches: a node spinning every 5 ms on a timer used 18 % of a core that way
# against 3 % leaving them with the receiver thread.
DIRECT_POLL_MIN_S = 0.01


class Timer:
    def __init__(self, period_s: float, callback: Callable[[], Any]):
        self.period_s = float(period_s)
        self.callback = callback
        self.next_at = time.monotonic() + self.period_s


class Node:
    """Base class of every node. Subclass, set NAME and PARAMS, implement setup()."""

    NAME = "node"
    PARAMS: dict[str, Any] = {}
    TOPICS: tuple[str, ...] = ()  # topics it advertises or subscribes by name (facesculpt.runtime.topics)
    DIAGNOSTICS_PERIOD_S = 1.0

    def __init__(self, name: str | None = None, params: dict | None = None, remap: dict | None = None,
                 master: str | None = None, transport: str = "ipc", host: str = "127.0.0.1",
                 security=None):
        self.name = name or self.NAME
        self.log = logging.getLogger(f"facesculpt.{self.name}")
        self.params = Params(**resolve_params(self.name, self.PARAMS, params or {}))
        self.remap = dict(remap or {})
        self.master = master or master_address()
        self.transport = transport
        self.host = host              # the address tcp publishers bind to (loopback unless told)
        # CURVE keys from the argument or $FACESCULPT_KEYS (facesculpt.runtime.security); None: no security.
        from facesculpt.runtime.security import Security

        self.security = security if security is not None else Security.from_env()
        self._check_exposure()
        self.ctx = zmq.Context()
        # The ZAP handler must run before the first bind, or CURVE servers would admit anyone.
        self._authenticator = self.security.start_authenticator(self.ctx) if self.security else None
        self.cond = threading.Condition()
        self.receiver = Receiver(self.ctx, self.cond, self.security)
        self.publishers: dict[str, Publisher] = {}
        self.subscriptions: list[Subscription] = []
        self.timers: list[Timer] = []
        self.counters: dict[str, int] = {}
        self.stage_times: dict[str, list[float]] = {}
        self.errors = 0
        self.last_error = ""
        self.exit_code = 0            # what run() returns (EXIT_STOP_GRAPH after stop_graph())
        self.running = False
        self._stopped = threading.Event()
        self.link = MasterLink(self)
        self._diag_pub: Publisher | None = None
        self._diag_window: dict[str, float] = {}

    # -- parameters ---------------------------------------------------------------------------
    @classmethod
    def default_params(cls) -> dict[str, Any]:
        """``{name: default}`` of this node's parameters."""
        return default_values(cls.PARAMS)

    def _check_exposure(self) -> None:
        """Secure by default: no publisher on a network address and no link to a master on
        another host without CURVE keys, unless ``$FACESCULPT_INSECURE`` says so (then one
        warning line). Raises SecurityError with the reason."""
        insecure = insecure_allowed()
        checks = [(f"node {self.name}'s link to the master", self.master)]
        if self.transport == "tcp":
            checks.append((f"node {self.name}'s publishers", f"tcp://{self.host}:*"))
        for what, address in checks:
            warning = check_exposure(what, address, self.security, insecure)
            if warning:
                self.log.warning("%s", warning)

    def resolve(self, topic: str) -> str:
        """Apply this node's remaps to a topic name."""
        return self.remap.get(topic, topic)

    # -- graph API ---------------------------------------------------------------------------
    def advertise(self, topic: str, msg_type: type[Message] | None, *,
                  qos: QoSProfile = SENSOR_DATA) -> Publisher:
        """Publish ``msg_type`` on ``topic`` (remapped), delivered as ``qos`` says
        (:mod:`facesculpt.runtime.qos`): e.g. ``LATCHED``, the master keeps the last message
        for nodes that join later; ``EVENTS``, block instead of dropping."""
        check_declared(self, topic)
        topic = self.resolve(topic)
        pub = Publisher(self.ctx, topic, msg_type, qos=qos, endpoint=new_endpoint(self.transport, self.host),
                        on_latch=self.link.push_latched, security=self.security)
        self.publishers[topic] = pub
        self.link.invalidate()  # re-register everything, including this publisher
        return pub

    def subscribe(self, topic: str, msg_type: type[Message] | None, callback: Callable, *,
                  qos: QoSProfile = SENSOR_DATA, raw: bool = False) -> Subscription:
        """Call ``callback(msg)`` for messages on ``topic`` (remapped), delivered as ``qos`` says.

        ``SENSOR_DATA`` (the default): the callback gets the newest message when it is
        free; a ``KEEP_ALL`` profile (``EVENTS``, ``EVERY_MESSAGE``) delivers every message in
        order, up to its depth. ``msg_type=None`` accepts any registered type. ``raw=True``
        calls ``callback(msg, frames)`` with the received frames as well (for recording).
        """
        check_declared(self, topic)
        sub = Subscription(self.resolve(topic), msg_type, callback, qos=qos, raw=raw)
        self.subscriptions.append(sub)
        self.receiver.add(sub)
        self.link.invalidate()
        return sub

    def timer(self, period_s: float, callback: Callable[[], Any]) -> Timer:
        """Call ``callback()`` every ``period_s`` seconds on the node's thread."""
        t = Timer(period_s, callback)
        self.timers.append(t)
        return t

    @contextlib.contextmanager
    def stage(self, name: str):
        """Time a block; the mean per diagnostics period is published as stages_ms[name]."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.stage_times.setdefault(name, []).append((time.perf_counter() - t0) * 1000.0)

    def count(self, name: str, n: int = 1) -> None:
        """Increase a named counter reported in diagnostics."""
        self.counters[name] = self.counters.get(name, 0) + n

    def stop_graph(self) -> None:
        """End this node with :data:`EXIT_STOP_GRAPH`: the user asked the whole graph to stop."""
        self.exit_code = EXIT_STOP_GRAPH
        self.shutdown()

    def shutdown(self) -> None:
        """Ask the node to stop (safe from any thread and from signal handlers)."""
        self.running = False
        self._stopped.set()
        # No lock here: this may run in a signal handler while the node's thread
        # holds the condition; spin() waits with a short timeout and sees the flag.

    # -- hooks for subclasses ---------------------------------------------------------------------
    def setup(self) -> None:
        """Advertise, subscribe, start timers. Called once before spinning."""

    def teardown(self) -> None:
        """Release resources. Called once after spinning, also after an error."""

    def after_messages(self) -> None:
        """Called after each batch of message callbacks (the messages that were waiting when the
        node last looked), before timers: a node that falls behind can act on the newest of them
        only (the renderer renders only the newest frame of a backlog)."""

    # -- running ---------------------------------------------------------------------------------
    def start(self) -> None:
        """Set up and connect without spinning (for tests and embedding)."""
        self.setup()
        self._diag_pub = self.advertise(DIAGNOSTICS_TOPIC, Diagnostics)
        self.timer(self.DIAGNOSTICS_PERIOD_S, self._publish_diagnostics)
        self.receiver.start()
        self.link.start()
        self.running = not self._stopped.is_set()  # a stop asked for during setup holds

    def spin_once(self, timeout_s: float = 0.05) -> int:
        """Run what is ready (callbacks, due timers), waiting up to ``timeout_s``. Returns callbacks run."""
        now = time.monotonic()
        wait = timeout_s
        if self.timers:
            wait = max(0.0, min(wait, min(t.next_at for t in self.timers) - now))
        ready = []
        rx = self.receiver
        if wait >= DIRECT_POLL_MIN_S and not self._has_ready():
            # A long wait: this thread polls the sockets itself (no thread switch between a
            # message's arrival and its callback); the receiver thread drains them the rest of the time.
            rx.take_sockets()
            try:
                # Look again now that the receiver thread can deliver nothing more: it may have
                # delivered between the first look and the hand-over.
                rx.receive(0.0 if self._has_ready() else wait)
            finally:
                rx.return_sockets()
        else:
            # A short wait (a fast timer is due): the hand-over of the sockets would cost more than
            # it saves, so the receiver thread keeps them and wakes this one when something came.
            with self.cond:
                if not self._has_ready():
                    self.cond.wait(wait)
        with self.cond:
            for sub in self.subscriptions:
                if sub.queued:
                    while sub.pending:
                        ready.append((sub, sub.pending.popleft()))
                elif sub.latest is not None:
                    ready.append((sub, sub.latest))
                    sub.latest = None
        ran = 0
        for sub, (msg, frames) in ready:
            if not self.running:
                break
            sub.delivered += 1
            sub.last_stamp = msg.stamp
            if msg.stamp:
                sub.last_take_age_ms = (time.time_ns() - msg.stamp) / 1e6
            self._call(sub.callback, msg, frames) if sub.raw else self._call(sub.callback, msg)
            ran += 1
        if ran and self.running:
            self._call(self.after_messages)
        now = time.monotonic()
        for t in self.timers:
            if now >= t.next_at and self.running:
                t.next_at = max(t.next_at + t.period_s, now)
                self._call(t.callback)
                ran += 1
        return ran

    def _has_ready(self) -> bool:
        return any(s.pending if s.queued else s.latest is not None for s in self.subscriptions)

    def _call(self, fn: Callable, *args) -> None:
        try:
            fn(*args)
        except Exception as exc:  # a callback error is counted and logged; the node goes on
            self.errors += 1
            self.last_error = f"{type(exc).__name__}: {exc}"
            if self.errors <= 5 or self.errors % 100 == 0:
                self.log.exception("error in %s (%d so far)", getattr(fn, "__name__", fn), self.errors)

    def spin(self) -> None:
        """Run until shutdown() or SIGINT/SIGTERM."""
        while self.running:
            self.spin_once(0.1)

    def close(self) -> None:
        """Stop threads, call teardown(), close sockets."""
        self.running = False
        with contextlib.suppress(Exception):
            self.teardown()
        self.receiver.stop()
        if self.receiver.is_alive():
            self.receiver.join(1.0)
        if not self.receiver.is_alive():
            self.receiver.close_sockets()  # never started: its sockets are still open
        # Flush what the publishers still hold (bounded by their linger) while we are still
        # registered: unregistering first would make subscribers disconnect and lose it.
        for pub in self.publishers.values():
            pub.close()
        if self._authenticator is not None:
            self._authenticator.stop()
        self.ctx.term()
        self.link.stopping = True
        self.link.wake.set()
        if self.link.is_alive():
            self.link.join(2.0)

    def run(self) -> int:
        """setup + spin + teardown, with SIGINT/SIGTERM handled; returns an exit code."""
        def _on_signal(signum, frame):
            if self._stopped.is_set():  # e.g. the terminal's Ctrl-C, then the launcher's SIGTERM: one line
                return
            # Flag first: a second signal that lands while this one is logging runs its handler
            # inside this one, and must find the node already stopping.
            self._stopped.set()
            self.log.info("stopping (%s)", signal.Signals(signum).name)
            self.shutdown()
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, _on_signal)
            signal.signal(signal.SIGTERM, _on_signal)
            held = held_signal()  # one that came while the process was starting: stop before setup
            if held is not None:
                _on_signal(held, None)
        try:
            try:
                if not self._stopped.is_set():
                    self.start()
            except ParameterError as exc:  # e.g. ConfigurationError from setup: one sentence, no respawn
                print(f"facesculpt: {exc}", file=sys.stderr, flush=True)
                return EXIT_BAD_PARAMETER
            self.spin()
        finally:
            self.close()
        return self.exit_code

    @classmethod
    def main(cls, argv: list[str] | None = None) -> None:
        """Entry point for a node in its own script: ``python my_node.py gain=2 --name n``. Logs as
        `facesculpt run` does (INFO and up, with time and node name) unless logging is set up."""
        if not logging.getLogger().handlers:
            logging.basicConfig(level=logging.INFO, format=LOG_FORMAT, datefmt="%H:%M:%S")
        sys.exit(run_node(cls, sys.argv[1:] if argv is None else argv))

    # -- diagnostics -----------------------------------------------------------------------------
    def diagnostics(self) -> dict:
        """The figures published on `diagnostics` (also used by tests)."""
        now_wall = time.monotonic()
        period = max(1e-3, now_wall - self._diag_window.get("at", now_wall - self.DIAGNOSTICS_PERIOD_S))
        self._diag_window["at"] = now_wall
        values: dict[str, Any] = {"rate_hz": {}, "age_ms": {}, "received": {}, "dropped": {},
                                  "malformed": {}, "published": {}, "subscribers": {}, "publisher_lost_s": {}}
        now = time.monotonic()
        with self.cond:
            for sub in self.subscriptions:
                prev = self._diag_window.get("sub:" + sub.topic, 0)
                values["rate_hz"][sub.topic] = round((sub.delivered - prev) / period, 2)
                self._diag_window["sub:" + sub.topic] = sub.delivered
                values["age_ms"][sub.topic] = (None if math.isnan(sub.last_take_age_ms)
                                               else round(sub.last_take_age_ms, 2))
                values["received"][sub.topic] = sub.received
                values["dropped"][sub.topic] = sub.dropped
                values["malformed"][sub.topic] = sub.malformed
                if sub.publisher_lost_at is not None:
                    values["publisher_lost_s"][sub.topic] = round(now - sub.publisher_lost_at, 1)
        for topic, pub in self.publishers.items():
            values["published"][topic] = pub.count
            values["subscribers"][topic] = pub.subscriber_count()  # who is connected now, not who registered
        stages = {k: round(sum(v) / len(v), 3) for k, v in self.stage_times.items() if v}
        self.stage_times = {k: [] for k in self.stage_times}
        values.update(errors=self.errors, last_error=self.last_error, stages_ms=stages,
                      counters=dict(self.counters))
        return values

    def _publish_diagnostics(self) -> None:
        if self._diag_pub is not None:
            self._diag_pub.publish(Diagnostics(stamp=time.time_ns(), node=self.name, pid=os.getpid(),
                                               values=self.diagnostics()))


# -- loading and running nodes ----------------------------------------------------------------------
def load_node_class(spec: str, builtin: dict[str, str] | None = None) -> type[Node]:
    """A short name from ``builtin`` (``{"camera": "module:Class"}``, given by the application:
    the runtime knows no node), ``module:Class`` or ``path/to/file.py:Class``."""
    builtin = builtin or {}
    target = builtin.get(spec, spec)
    module_name, sep, class_name = target.rpartition(":")
    if not sep or not module_name or not class_name:
        known, close = ", ".join(sorted(builtin)) or "none", difflib.get_close_matches(spec, list(builtin), n=1)
        raise ValueError(f"unknown node {spec!r}" + (f" (did you mean {close[0]}?)" if close else "")
                         + f": give a built-in name ({known}), module:Class or path/file.py:Class")
    if module_name.endswith(".py"):
        path = Path(module_name)
        if not path.is_file():
            raise FileNotFoundError(f"node file {path} not found")
        mod_spec = importlib.util.spec_from_file_location(path.stem, path)
        module = importlib.util.module_from_spec(mod_spec)
        sys.modules[path.stem] = module
        mod_spec.loader.exec_module(module)
    else:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            raise ValueError(f"node {spec!r}: cannot import {module_name} ({exc})") from None
    cls = getattr(module, class_name, None)
    if not (isinstance(cls, type) and issubclass(cls, Node)):
        raise ValueError(f"node {spec!r}: {class_name} is not a facesculpt.runtime.node.Node subclass in {module_name}")
    return cls


def params_help(cls: type[Node]) -> str:
    """Every parameter of ``cls`` with its type, default, range or choices and description."""
    params = declared(cls.PARAMS)
    if not params:
        return "parameters: none"
    lines = ["parameters (name=value; a value out of its range or choices stops the node, "
             f"exit code {EXIT_BAD_PARAMETER}):"]
    width = max(len(name) for name in params)
    for name, param in params.items():
        lines.append(f"  {name:<{width}}  {param.help_text()}")
    return "\n".join(lines)


def node_parser(cls: type[Node]):
    """``facesculpt run NODE``'s parser: the first line of the node's docstring, its parameters."""
    import argparse

    parser = argparse.ArgumentParser(prog=f"facesculpt run {cls.NAME}",
                                     description=(cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else None,
                                     epilog=params_help(cls), formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--name", help=f"node name (default {cls.NAME})")
    parser.add_argument("--remap", action="append", default=[], metavar="FROM=TO", help="rename a topic")
    parser.add_argument("--config-json", help=argparse.SUPPRESS)  # used by `facesculpt launch`
    parser.add_argument("params", nargs="*", metavar="param=value", help="parameters (listed below)")
    return parser


def run_node(cls: type[Node], argv: list[str]) -> int:
    """Parse ``[--name N] [--remap from=to ...] [--config-json J] [param=value ...]`` and run.

    A parameter the node cannot run with (:class:`ParameterError`) is reported in one sentence
    and the exit code is :data:`EXIT_BAD_PARAMETER`, which the launcher does not respawn."""
    args = node_parser(cls).parse_args(argv)
    config = json.loads(args.config_json) if args.config_json else {}
    params = dict(config.get("params", {}))
    params.update(parse_assignments(args.params))
    remap = dict(config.get("remap", {}))
    remap.update(parse_assignments(args.remap))
    # Many processes share few cores: one BLAS and OpenCV thread per node unless told otherwise.
    limit_threads(int(os.environ.get("FACESCULPT_THREADS", "1")))
    try:
        node = cls(name=args.name or config.get("name"), params=params, remap=remap,
                   transport=config.get("transport", "ipc"), host=config.get("host", "127.0.0.1"))
    except (ParameterError, SecurityError) as exc:
        print(f"facesculpt: {exc}", file=sys.stderr)
        return EXIT_BAD_PARAMETER
    return node.run()
