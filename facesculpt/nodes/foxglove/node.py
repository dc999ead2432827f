"""The Foxglove node: ``facesculpt run foxglove [port=8765] [host=127.0.0.1]``.

Serves the running graph live over the Foxglove WebSocket protocol (``foxglove-sdk``'s server,
subprotocol ``foxglove.websocket.v1``): open ``ws://127.0.0.1:8765`` in Foxglove (app or
browser, "Open connection", Foxglove WebSocket). The channels are those of
:mod:`.bridge` (images, camera calibration, landmark points, a 3D scene of the fitted and
deformed meshes and the handles, diagnostics as JSON). A client may publish JSON objects on
``input/events`` (Foxglove's publish panel; client-publish capability): each one becomes an
``InputEvent`` (:func:`.convert.input_event_from_json`) published into the graph with the
reliable, queued profile, as from any input node. One that is not a valid event is dropped,
counted (``bad_input``) and named in one log line.

The server binds ``host`` (loopback by default); any other address needs the same explicit
consent as the rest of the graph (``FACESCULPT_INSECURE=1``), since anyone reaching the port
sees the camera and can move the face. Diagnostics counters: ``clients``, ``events_in``,
``bad_input``, ``logged``.
"""

from __future__ import annotations

import collections
import threading

from facesculpt.msgs import Deformation, Diagnostics, FaceLandmarks, FaceModel, FaceState, Image, InputEvent
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import ConfigurationError, Param
from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE, LATCHED, SENSOR_DATA
from facesculpt.runtime.security import SecurityError, check_exposure, insecure_allowed

from .bridge import FoxgloveBridge
from .convert import input_event_from_json

INPUT_TOPIC = "input/events"


class _Listener:
    """The server's callbacks (run on its own threads): client channels and their messages are
    queued for the node's thread."""

    def __init__(self):
        self.lock = threading.Lock()
        self.channels: dict[tuple[int, int], tuple[str, str]] = {}
        self.inbox: collections.deque = collections.deque()
        self.clients: set[int] = set()

    def on_subscribe(self, client, channel) -> None:
        with self.lock:
            self.clients.add(client.id)

    def on_client_advertise(self, client, channel) -> None:
        with self.lock:
            self.channels[(client.id, channel.id)] = (channel.topic, channel.encoding)

    def on_client_unadvertise(self, client, client_channel_id: int) -> None:
        with self.lock:
            self.channels.pop((client.id, client_channel_id), None)

    def on_message_data(self, client, client_channel_id: int, data: bytes) -> None:
        with self.lock:
            topic, encoding = self.channels.get((client.id, client_channel_id), ("", ""))
        self.inbox.append((topic, encoding, bytes(data)))


class FoxgloveNode(Node):
    """Serves the running graph to Foxglove over its WebSocket protocol (images, landmarks, 3D scene)."""

    NAME = "foxglove"
    TOPICS = ("input/events", "camera/image", "render/image", "face/landmarks", "face/state", "face/model",
              "face/deformation")
    PARAMS = {
        "port": Param(8765, "TCP port of the Foxglove WebSocket server (0: any free port)", range=(0, 65535)),
        "host": Param("127.0.0.1", "address the server binds; not loopback needs FACESCULPT_INSECURE=1"),
        "jpeg_quality": Param(80, "images as JPEG of this quality (CompressedImage); 0 sends them raw (RawImage)",
                              range=(0, 100)),
        "units_to_m": Param(0.001, "metres per unit of the face model's vertices (mm: 0.001)", range=(1e-6, 1.0)),
        "handle_diameter_m": Param(0.006, "diameter of the spheres drawn at the handles, m", range=(0.0, 1.0)),
    }

    def setup(self):
        import foxglove
        from foxglove.websocket import Capability

        p = self.params
        try:
            warning = check_exposure(f"node {self.name}'s Foxglove server", p.host, None, insecure_allowed())
        except SecurityError as exc:
            raise ConfigurationError(str(exc)) from None
        if warning:
            self.log.warning("%s", warning)
        self.bridge = FoxgloveBridge(jpeg_quality=p.jpeg_quality, units_to_m=p.units_to_m,
                                     handle_diameter_m=p.handle_diameter_m)
        self.listener = _Listener()
        try:
            self.server = foxglove.start_server(name="facesculpt", host=p.host, port=p.port,
                                                capabilities=[Capability.ClientPublish],
                                                supported_encodings=["json"], server_listener=self.listener)
        except Exception as exc:  # the port is taken, the host is not ours: one sentence, no respawn
            raise ConfigurationError(f"foxglove: cannot serve on {p.host}:{p.port}: {exc}") from None
        self.log.info("Foxglove WebSocket server on ws://%s:%d (open it in Foxglove: Open connection)",
                      p.host, self.server.port)
        self.events = self.advertise(INPUT_TOPIC, InputEvent, qos=EVENTS)
        for topic in ("camera/image", "render/image"):
            self.subscribe(topic, Image, lambda m, t=topic: self._show(t, m), qos=SENSOR_DATA)
        self.subscribe("face/landmarks", FaceLandmarks, lambda m: self._show("face/landmarks", m))
        self.subscribe("face/state", FaceState, lambda m: self._show("face/state", m), qos=EVERY_MESSAGE)
        self.subscribe("face/model", FaceModel, lambda m: self._show("face/model", m), qos=LATCHED)
        self.subscribe("face/deformation", Deformation, lambda m: self._show("face/deformation", m), qos=LATCHED)
        self.subscribe("diagnostics", Diagnostics, lambda m: self._show("diagnostics", m), qos=EVERY_MESSAGE)
        self.timer(0.01, self._drain_input)

    def _show(self, topic: str, msg) -> None:
        import time

        with self.stage("foxglove"):
            if self.bridge.handle(topic, msg, time.time_ns()):
                self.count("logged")

    def _drain_input(self) -> None:
        """Publish what clients sent on input/events; drop and name anything else."""
        import time

        inbox = self.listener.inbox
        while inbox:
            topic, encoding, data = inbox.popleft()
            try:
                if topic != self.resolve(INPUT_TOPIC) or encoding != "json":
                    raise ValueError(f"a client published on {topic or 'an unknown channel'!r} ({encoding or '?'}); "
                                     f"only JSON on {INPUT_TOPIC} is taken")
                event = input_event_from_json(data)
            except ValueError as exc:
                self.count("bad_input")
                self.log.warning("dropped a message from Foxglove: %s", exc)
                continue
            event.stamp = event.stamp or time.time_ns()
            self.events.publish(event)
            self.count("events_in")
        self.counters["clients"] = len(self.listener.clients)

    def teardown(self):
        server = getattr(self, "server", None)
        if server is not None:
            server.stop()
        bridge = getattr(self, "bridge", None)
        if bridge is not None:
            bridge.close()


if __name__ == "__main__":
    FoxgloveNode.main()
