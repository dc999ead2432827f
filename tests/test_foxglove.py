"""Foxglove: the node serves a running graph over the Foxglove WebSocket protocol to a client
written here (images and the 3D scene received and decoded from the advertised protobuf
schemas; an InputEvent published from the client reaches input/events and moves the face), and
`bag export --foxglove` writes a recording with the same schemas."""

from __future__ import annotations

import asyncio
import base64
import json
import struct

import cv2
import numpy as np
import pytest
from conftest import free_port
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader

from facesculpt.msgs import Deformation, Diagnostics, FaceLandmarks, FaceModel, FaceState, Image, InputEvent
from facesculpt.nodes.foxglove.convert import input_event_from_json
from facesculpt.runtime.bag import BagWriter
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE, LATCHED

websockets = pytest.importorskip("websockets")
# foxglove-sdk 0.30 speaks the protocol as "foxglove.sdk.v1"; older servers as "foxglove.websocket.v1".
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def proto_class(schema_name: str, descriptor_set: bytes):
    """The message class of a protobuf schema given as a FileDescriptorSet (Foxglove's schemas)."""
    pool = descriptor_pool.DescriptorPool()
    for fd in descriptor_pb2.FileDescriptorSet.FromString(descriptor_set).file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def test_input_events_from_json_are_checked():
    event = input_event_from_json(b'{"kind": "move", "landmark": "chin", "handle": 3, "vector": [0, -1, 2]}')
    assert (event.kind, event.landmark, event.handle, event.source) == ("move", "chin", 3, "foxglove")
    assert event.vector.dtype == np.float32 and event.vector.tolist() == [0.0, -1.0, 2.0]
    turn = input_event_from_json(b'{"kind": "pose", "pose": [2, -1, 0, 0, 0, 5], "face": 1}')
    assert (turn.kind, turn.face, turn.pose.tolist()) == ("pose", 1, [2.0, -1.0, 0.0, 0.0, 0.0, 5.0])
    for bad, why in ((b"not json", "not JSON"), (b'{"kind": "pose", "pose": [2, 1]}', "'pose' must be a list of 6"), (b"[1]", "not a JSON object"), (b'{"kind": "fly"}', "kind 'fly'"),
                     (b'{"kind": "press", "x": "left"}', "'x' must be a number"),
                     (b'{"kind": "move", "vector": [1, 2]}', "'vector' must be a list of 3"),
                     (b'{"kind": "press", "colour": 1}', "unknown fields colour")):
        with pytest.raises(ValueError, match=why):
            input_event_from_json(bad)


class _Client:
    """A Foxglove WebSocket client: subscribes to topics, collects decoded messages, publishes JSON."""

    def __init__(self, port: int):
        self.port = port
        self.channels: dict[int, dict] = {}
        self.received: dict[str, list] = {}

    async def session(self, topics, until, publish=(), timeout=60.0):
        url = f"ws://127.0.0.1:{self.port}"
        async with websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
            assert ws.subprotocol in SUBPROTOCOLS
            info = json.loads(await ws.recv())
            assert info["op"] == "serverInfo" and "clientPublish" in info["capabilities"]
            subs, classes = {}, {}
            loop = asyncio.get_running_loop()
            deadline = loop.time() + timeout
            sent = False
            while not until(self.received) and loop.time() < deadline:
                try:
                    msg = await asyncio.wait_for(ws.recv(), 1.0)
                except asyncio.TimeoutError:
                    msg = None
                if isinstance(msg, str):
                    d = json.loads(msg)
                    if d["op"] == "advertise":
                        for ch in d["channels"]:
                            self.channels[ch["id"]] = ch
                            if ch["topic"] in topics and ch["id"] not in subs.values():
                                sid = len(subs) + 1
                                subs[sid] = ch["id"]
                                classes[sid] = (ch["topic"], self._decoder(ch))
                                await ws.send(json.dumps({"op": "subscribe",
                                                          "subscriptions": [{"id": sid, "channelId": ch["id"]}]}))
                elif isinstance(msg, bytes) and msg[0] == 0x01:            # message data
                    sid, log_time = struct.unpack_from("<IQ", msg, 1)
                    topic, decoder = classes[sid]
                    self.received.setdefault(topic, []).append((log_time, decoder(msg[13:])))
                if publish and not sent and len(subs) == len(topics):
                    await self._publish(ws, publish)
                    sent = True

    @staticmethod
    def _decoder(ch):
        if ch["encoding"] == "protobuf":
            cls = proto_class(ch["schemaName"], base64.b64decode(ch["schema"]))
            return cls.FromString
        assert ch["encoding"] == "json"
        return json.loads

    @staticmethod
    async def _publish(ws, payloads):
        await ws.send(json.dumps({"op": "advertise", "channels": [
            {"id": 7, "topic": "input/events", "encoding": "json", "schemaName": "facesculpt.InputEvent"}]}))
        for payload in payloads:
            await ws.send(struct.pack("<BI", 0x01, 7) + payload)


@pytest.mark.slow
def test_the_node_serves_the_graph_to_a_foxglove_client_and_takes_input(graph, data_dir, models_dir):
    port = free_port()
    events: list[InputEvent] = []
    deformations: list[Deformation] = []
    diags: dict = {}
    watcher = graph.node(Node(name="watcher"))
    watcher.subscribe("input/events", InputEvent, events.append, qos=EVENTS)
    watcher.subscribe("face/deformation", Deformation, deformations.append, qos=LATCHED)
    watcher.subscribe("diagnostics", Diagnostics, lambda m: diags.__setitem__(m.node, m.values), qos=EVERY_MESSAGE)
    graph.spawn("run", "foxglove", f"port={port}")
    for name in ("landmarks", "fitter", "deformer"):
        graph.spawn("run", name)
    assert graph.spin_until(watcher, lambda: {"foxglove", "landmarks", "fitter", "deformer"} <= set(diags), 60)
    graph.spawn("run", "camera", f"source={data_dir / 'video' / 'd0.mp4'}", "fps=8", "loop=true", "width=320")
    assert graph.spin_until(watcher, lambda: diags["foxglove"]["subscribers"].get("input/events", 0) >= 2, 30)

    client = _Client(port)
    moves = [json.dumps({"kind": "move", "landmark": "nose_tip", "handle": 3, "vector": [0, 0, 4]}).encode()] * 3
    bad = b'{"kind": "fly"}'

    def enough(got):
        deformed = [u for _, u in got.get("face/scene", []) if any(e.id == "deformed/0" for e in u.entities)]
        return len(got.get("camera/image", [])) >= 5 and len(deformed) >= 2

    import threading

    thread = threading.Thread(target=lambda: asyncio.run(client.session(
        ["camera/image", "face/scene"], enough, publish=[*moves, bad], timeout=90)))
    thread.start()
    while thread.is_alive():
        watcher.spin_once(0.05)
    thread.join()

    images = client.received.get("camera/image", [])
    assert len(images) >= 5, client.received.keys()
    first = images[-1][1]
    assert first.format == "jpeg"
    assert cv2.imdecode(np.frombuffer(first.data, np.uint8), cv2.IMREAD_COLOR).shape == (320, 320, 3)
    scenes = [u for _, u in client.received["face/scene"]]
    fitted = next(e for u in scenes for e in u.entities if e.id == "fitted/0")
    assert fitted.frame_id == "camera" and len(fitted.triangles[0].points) == 468
    assert len(fitted.triangles[0].indices) % 3 == 0 and max(fitted.triangles[0].indices) == 467
    z = np.array([p.z for p in fitted.triangles[0].points])
    assert 0.05 < z.mean() < 5.0                                 # metres in front of the camera
    deformed = next(e for u in scenes for e in u.entities if e.id == "deformed/0")
    assert len(deformed.spheres) >= 1                            # the handle on the nose tip

    assert graph.spin_until(watcher, lambda: len(events) >= 3 and diags["foxglove"]["counters"].get("bad_input"), 10)
    assert [(e.kind, e.landmark, e.source, e.vector.tolist()) for e in events[:3]] == \
        [("move", "nose_tip", "foxglove", [0.0, 0.0, 4.0])] * 3
    assert diags["foxglove"]["counters"]["events_in"] == 3 and diags["foxglove"]["counters"]["bad_input"] == 1
    moved = max(float(np.abs(d.displacement).max()) for d in deformations if d.displacement.size)
    assert moved > 5.0                                           # 3 x 4 mm toward the camera, as ARAP spreads it


def _tetra_bag(path):
    """A small recording of every kind the bridge shows, on a tetrahedron "face" (mm)."""
    V = np.array([[0, 0, 0], [40, 0, 0], [0, 40, 0], [0, 0, 40]], np.float32)
    T = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]], np.int32)
    K = np.array([[300, 0, 160], [0, 300, 120], [0, 0, 1]], np.float64)
    t0 = 1_700_000_000_000_000_000
    with BagWriter(path) as w:
        w.write(t0, "face/model", FaceModel(stamp=t0, vertices=V, triangles=T).to_frames())
        w.write(t0 + 1, "face/deformation", Deformation(stamp=t0, displacement=np.tile([[0, 0, 5]], (4, 1)).astype(
            np.float32), handles=np.array([3], np.int32)).to_frames())
        for i in range(3):
            t = t0 + (i + 1) * 100_000_000
            img = np.full((240, 320, 3), 40 * i, np.uint8)
            w.write(t, "camera/image", Image(stamp=t, image=img, K=K).to_frames())
            w.write(t + 1, "face/landmarks", FaceLandmarks(stamp=t, points=np.ones((1, 468, 3), np.float32),
                                                           scores=np.ones(1, np.float32),
                                                           rois=np.zeros((1, 5), np.float32)).to_frames())
            state = FaceState(stamp=t, vertices=V + np.float32([0, 0, 500]), projected=np.zeros((4, 2), np.float32),
                              t=np.array([0, 0, 500.0]))
            w.write(t + 2, "face/state", state.to_frames())
            w.write(t + 3, "diagnostics", Diagnostics(stamp=t, node="fitter", values={"rate_hz": 10.0}).to_frames())
    return V


def test_bag_export_writes_foxglove_schemas(graph, tmp_path):
    bag, out = tmp_path / "rec.mcap", tmp_path / "foxglove.mcap"
    V = _tetra_bag(bag)
    res = graph.run("bag", "export", "--foxglove", str(bag), "-o", str(out))
    assert res.returncode == 0, res.stderr
    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        kinds = {c.topic: (summary.schemas[c.schema_id].name, c.message_encoding) for c in summary.channels.values()}
        assert kinds == {"camera/image": ("foxglove.CompressedImage", "protobuf"),
                         "camera/calibration": ("foxglove.CameraCalibration", "protobuf"),
                         "face/landmarks": ("foxglove.ImageAnnotations", "protobuf"),
                         "face/scene": ("foxglove.SceneUpdate", "protobuf"),
                         "diagnostics": ("facesculpt.Diagnostics", "json")}
        got: dict[str, list] = {}
        for schema, channel, message in reader.iter_messages():
            decode = json.loads if channel.message_encoding == "json" else proto_class(schema.name, schema.data).FromString
            got.setdefault(channel.topic, []).append((message.log_time, decode(message.data)))
    assert {t: len(v) for t, v in got.items()} == {"camera/image": 3, "camera/calibration": 3, "face/landmarks": 3,
                                                   "face/scene": 3, "diagnostics": 3}
    image = cv2.imdecode(np.frombuffer(got["camera/image"][2][1].data, np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (240, 320, 3) and abs(int(image.mean()) - 80) <= 2
    assert list(got["camera/calibration"][0][1].K) == [300, 0, 160, 0, 300, 120, 0, 0, 1]
    scene = got["face/scene"][0][1]
    fitted, deformed = (next(e for e in scene.entities if e.id == name) for name in ("fitted/0", "deformed/0"))
    pts = np.array([[p.x, p.y, p.z] for p in fitted.triangles[0].points])
    assert np.allclose(pts, (V + [0, 0, 500]) / 1000, atol=1e-6)          # mm -> m, camera frame
    moved = np.array([[p.x, p.y, p.z] for p in deformed.triangles[0].points])
    assert np.allclose(moved - pts, [0, 0, 0.005], atol=1e-6)             # the 5 mm edit (R = I, scale 1)
    (sphere,) = deformed.spheres
    assert np.isclose(sphere.pose.position.z, moved[3, 2])                # the handle on vertex 3
    assert got["diagnostics"][0][1] == {"node": "fitter", "pid": 0, "stamp": got["diagnostics"][0][1]["stamp"],
                                        "values": {"rate_hz": 10.0}}


def test_the_shipped_launch_files_start_foxglove_only_when_enabled():
    from facesculpt.paths import launch_file
    from facesculpt.runtime.launcher import load_launch

    for name in ("webcam", "video", "replay"):
        assert "foxglove" not in [s.name for s in load_launch(launch_file(name))]
        (spec,) = [s for s in load_launch(launch_file(name), ["foxglove.enabled=true", "foxglove.port=9001"])
                   if s.name == "foxglove"]
        assert spec.node == "foxglove" and spec.params["port"] == "9001"
    with pytest.raises(ValueError, match="enabled must be true or false"):
        load_launch(launch_file("webcam"), ["foxglove.enabled=maybe"])


def test_a_server_on_the_network_needs_explicit_consent(graph):
    out = graph.run("run", "foxglove", "host=0.0.0.0", f"port={free_port()}", timeout=30)
    assert out.returncode == 2, out.stderr
    assert "refusing to expose node foxglove's Foxglove server on 0.0.0.0" in out.stderr.strip().splitlines()[-1]
