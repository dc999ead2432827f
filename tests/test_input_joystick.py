"""The serial joystick node with real I/O: a pseudo-terminal pair (the slave's path as the port,
through a symlink the way udev names devices) and a TCP server on 127.0.0.1 (socket://).
The node runs as its own process (`facesculpt run joystick ...`)."""

from __future__ import annotations

import os
import random
import socket
import time

import numpy as np
import pytest

from facesculpt.geometry import axes_velocity
from facesculpt.msgs import Diagnostics, FaceModel, FaceState, InputEvent
from facesculpt.nodes.input.joystick import JoystickNode
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE


class Pty:
    """A pseudo-terminal whose slave is reachable as ``link`` (a symlink), pluggable."""

    def __init__(self, link):
        self.link = str(link)
        self.master = self.slave = None
        self.plug()

    def plug(self):
        self.master, self.slave = os.openpty()
        tmp = self.link + ".new"
        os.symlink(os.ttyname(self.slave), tmp)
        os.replace(tmp, self.link)

    def unplug(self):
        os.unlink(self.link)
        os.close(self.master)
        os.close(self.slave)
        self.master = self.slave = None

    def write(self, data: bytes):
        view = memoryview(data)
        while view:
            view = view[os.write(self.master, view):]

    def close(self):
        if self.master is not None:
            self.unplug()


class Listener:
    """Collects input/events (every one, in order) and the joystick's diagnostics."""

    def __init__(self, graph, name="joystick"):
        self.events: list[InputEvent] = []
        self.diag: dict = {}
        self.graph = graph
        self.node = Node(name="joystick_test_listener")
        self.node.subscribe("input/events", InputEvent, self.events.append, qos=EVENTS)
        self.node.subscribe("diagnostics", Diagnostics,
                            lambda m: self.diag.update(m.values) if m.node == name else None, qos=EVERY_MESSAGE)
        graph.node(self.node)

    def wait(self, predicate, timeout=10.0) -> bool:
        return self.graph.spin_until(self.node, predicate, timeout)

    def sync(self, device, timeout=15.0):
        """Toggle an unmapped button until its `buttons` event arrives: the port is open and
        the listener connected."""
        deadline = time.monotonic() + timeout
        bit = 0
        while time.monotonic() < deadline:
            bit ^= 1
            try:
                device.write(f"0 0 0 {bit << 7}\n".encode())
            except OSError:
                pass
            if self.wait(lambda: any(e.kind == "buttons" and e.buttons == bit << 7 for e in self.events), 0.2):
                return
        raise AssertionError("the joystick node never passed a line through")

    def fresh_diagnostics(self, timeout=5.0) -> dict:
        """The joystick's next diagnostics (published about once a second)."""
        self.diag.clear()
        assert self.wait(lambda: bool(self.diag), timeout), "no diagnostics from the joystick"
        return self.diag


@pytest.mark.timing
def test_pty_lines_become_events_with_the_right_axis_values(graph, tmp_path):
    pty = Pty(tmp_path / "joystick0")
    try:
        graph.spawn("run", "joystick", f"port={pty.link}", "grab_landmark=nose_tip", "speed_mm_s=50",
                    "deadzone=0.1")
        listener = Listener(graph)
        listener.sync(pty)
        listener.events.clear()
        start = time.monotonic()
        pty.write(b"0 0 0 1\n")  # grab button
        assert listener.wait(lambda: any(e.kind == "press" for e in listener.events))
        pressed_at = time.monotonic()
        press = [e for e in listener.events if e.kind == "press"][0]
        assert press.landmark == "nose_tip" and press.handle == 1 and press.source == "joystick"
        listener.events.clear()
        for _ in range(20):  # 0.5, -0.25, 1.0 held for ~0.2 s at 100 Hz
            pty.write(b"500 -250 1000 1\n")
            written_at = time.monotonic()
            time.sleep(0.01)
        pty.write(b"50 -50 99 1\n")  # inside the deadzone: no motion
        pty.write(b"0 0 0 3\n")  # release button
        assert listener.wait(lambda: any(e.kind == "release" for e in listener.events))
        released_at = time.monotonic()
        moves = [e for e in listener.events if e.kind == "move"]
        assert 1 <= len(moves) <= 20  # one per sample (samples read in one burst share a time)
        for m in moves:
            assert np.array_equal(m.axes, np.array([0.5, -0.25, 1.0], np.float32)) and m.buttons == 1
        velocity = axes_velocity([0.5, -0.25, 1.0], 50.0, 0.1)  # mm/s: x right, y up, z out
        total = np.sum([m.vector for m in moves], axis=0)
        assert np.allclose(total / np.linalg.norm(total), velocity / np.linalg.norm(velocity), atol=1e-4)
        # the handle moved at that velocity from the grab sample's arrival to the last sample's:
        # at least while the test was writing after the grab, at most while it waited in all
        moved_s = np.linalg.norm(total) / np.linalg.norm(velocity)
        assert written_at - pressed_at - 1e-3 <= moved_s <= released_at - start + 1e-3
        kinds = [e.kind for e in listener.events]
        assert kinds[-2:] == ["buttons", "release"] and kinds.count("move") == len(moves)
    finally:
        pty.close()


def test_the_pose_button_makes_the_axes_turn_the_head(graph, tmp_path):
    pty = Pty(tmp_path / "joystick0")
    try:
        graph.spawn("run", "joystick", f"port={pty.link}", "grab_landmark=nose_tip", "pose_speed_deg_s=40",
                    "deadzone=0.1")
        listener = Listener(graph)
        listener.sync(pty)
        listener.events.clear()
        pty.write(b"0 0 0 1\n")           # grab
        pty.write(b"0 0 0 9\n")           # pose mode on (bit 3), still holding the grab button
        for _ in range(15):
            pty.write(b"1000 0 -500 9\n")  # full right, half roll
            time.sleep(0.01)
        pty.write(b"0 0 0 1\n")           # the pose button let go: still in pose mode
        pty.write(b"0 0 0 9\n")           # pose mode off
        for _ in range(5):
            pty.write(b"1000 0 0 9\n")
            time.sleep(0.01)
        pty.write(b"0 0 0 3\n")           # release
        assert listener.wait(lambda: any(e.kind == "release" for e in listener.events))
        kinds = [e.kind for e in listener.events]
        poses = [e for e in listener.events if e.kind == "pose"]
        assert poses and all(e.kind != "move" for e in listener.events[:kinds.index("pose") + len(poses)])
        turn = np.sum([e.pose for e in poses], axis=0)
        assert turn[0] > 0 and turn[1] == 0 and turn[2] < 0 and not turn[3:].any()
        velocity = axes_velocity([1.0, 0.0, -0.5], 40.0, 0.1)   # deg/s of yaw, pitch, roll
        assert np.allclose(turn[:3] / np.linalg.norm(turn[:3]), velocity / np.linalg.norm(velocity), atol=1e-4)
        assert 0 < turn[0] <= 40.0 * 0.25 * 16       # at most 40 deg/s over the samples' intervals
        assert "move" in kinds[kinds.index("pose") + len(poses):]   # pose mode off: the handle moves again
    finally:
        pty.close()


@pytest.mark.slow
def test_unplug_and_replug_resume_without_restart(graph, tmp_path):
    pty = Pty(tmp_path / "joystick0")
    try:
        proc = graph.spawn("run", "joystick", f"port={pty.link}", "reconnect_max_s=0.5", "grab_button=-1",
                           "release_button=-1", "reset_button=-1")
        listener = Listener(graph)
        listener.sync(pty)
        for cycle in range(2):
            pty.unplug()
            time.sleep(0.6)  # the node notices, fails to reopen at least once, backs off
            pty.plug()
            listener.events.clear()
            listener.sync(pty)  # events resume through the new device, same process
            pty.write(f"{123 + cycle} -45 6 1\n".encode())
            assert listener.wait(lambda: any(e.kind == "buttons" and e.buttons == 1 for e in listener.events))
            event = [e for e in listener.events if e.buttons == 1][0]
            assert np.array_equal(event.axes, np.array([0.123 + 0.001 * cycle, -0.045, 0.006], np.float32))
        assert proc.poll() is None
        diag = listener.fresh_diagnostics()
        assert diag["counters"]["connects"] == 3 and diag["counters"]["disconnects"] == 2
        assert diag["counters"]["open_failures"] >= 2 and diag["connected"] is True
        assert diag["errors"] == 0
    finally:
        pty.close()


class LineServer:
    """A TCP server on 127.0.0.1 that a socket:// joystick connects to; stoppable and restartable."""

    def __init__(self):
        self.port = None
        self.listen = self.conn = None
        self.start()

    def start(self):
        self.listen = socket.socket()
        self.listen.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listen.bind(("127.0.0.1", self.port or 0))
        self.port = self.listen.getsockname()[1]
        self.listen.listen(1)
        self.listen.settimeout(0.05)
        self.conn = None

    def write(self, data: bytes):
        if self.conn is None:
            try:
                self.conn, _ = self.listen.accept()
            except TimeoutError:
                raise OSError("not connected yet") from None
        self.conn.sendall(data)

    def stop(self):
        if self.conn is not None:
            self.conn.close()
        self.listen.close()
        self.conn = None


@pytest.mark.slow
def test_socket_url_server_restart_resumes(graph):
    server = LineServer()
    try:
        proc = graph.spawn("run", "joystick", f"port=socket://127.0.0.1:{server.port}", "reconnect_max_s=0.5")
        listener = Listener(graph)
        listener.sync(server)
        server.stop()
        time.sleep(0.5)
        server.start()
        listener.events.clear()
        listener.sync(server)
        server.write(b"-1000 1000 -7 512\n")
        assert listener.wait(lambda: any(e.kind == "buttons" and e.buttons == 512 and e.axes[0] == -1.0
                                         for e in listener.events))
        assert proc.poll() is None
        diag = listener.fresh_diagnostics()
        assert diag["counters"]["connects"] == 2 and diag["counters"]["disconnects"] == 1
    finally:
        server.stop()


def garbage_lines(rng: random.Random, n: int) -> list[bytes]:
    """Lines that must all be rejected: every way a line can be wrong, none of them blank."""
    printable_or_not = [b for b in range(256) if b not in b"\n\r\t\x0b\x0c "]
    makers = [
        lambda: bytes(rng.choice(printable_or_not) for _ in range(rng.randint(1, 60))),
        lambda: " ".join(str(rng.randint(-1000, 1000)) for _ in range(rng.choice([1, 2, 3, 5, 6]))).encode(),
        lambda: f"{rng.randint(1001, 99999)} 0 0 0".encode(),
        lambda: f"0 {-rng.randint(1001, 99999)} 0 0".encode(),
        lambda: f"0 0 0 {-rng.randint(1, 9)}".encode(),
        lambda: f"{rng.random():.3f} 0 0 0".encode(),
        lambda: b"1 2 3 4" * rng.randint(30, 80),  # overlong
        lambda: "\u0661 2 3 4".encode(),  # an Arabic-Indic digit
        lambda: b"hello joystick",
        lambda: b"0 0 0 0x1",
    ]
    return [rng.choice(makers)() for _ in range(n)]


def test_garbage_between_valid_lines_loses_none_and_is_counted(graph, tmp_path):
    pty = Pty(tmp_path / "joystick0")
    try:
        graph.spawn("run", "joystick", f"port={pty.link}", "grab_button=-1", "release_button=-1", "reset_button=-1")
        listener = Listener(graph)
        listener.sync(pty)
        listener.events.clear()
        rng = random.Random(7)
        garbage = garbage_lines(rng, 1000)
        assert all(line.strip() and b"\n" not in line for line in garbage)
        expected = []
        stream = bytearray()
        for i in range(51):  # 51 valid lines with 20 garbage lines between each two: 1000 garbage lines
            x, mask = 20 * i - 500, 1 << (8 + i % 2)  # the mask changes every line: one event each
            stream += f"{x} {-i} {i} {mask}\n".encode()
            expected.append((x, mask))
            if i < 50:
                stream += b"\n".join(garbage[20 * i:20 * i + 20]) + b"\n"
        pty.write(bytes(stream))
        got = lambda: [e for e in listener.events if e.kind == "buttons"]  # noqa: E731
        assert listener.wait(lambda: len(got()) >= 51, 15)
        assert [(round(float(e.axes[0]) * 1000), e.buttons) for e in got()] == expected
        diag = listener.fresh_diagnostics()
        assert diag["counters"]["malformed"] == 1000
        assert diag["counters"]["lines"] >= 51 and diag["errors"] == 0
    finally:
        pty.close()


def test_missing_device_one_clear_sentence_and_the_node_keeps_trying(graph, tmp_path):
    err = tmp_path / "stderr.txt"
    with open(err, "w") as f:
        proc = graph.spawn("run", "joystick", "port=/dev/no-such-joystick", "reconnect_max_s=0.2", stderr=f)
    listener = Listener(graph)
    assert listener.wait(lambda: listener.diag.get("counters", {}).get("open_failures", 0) >= 3, 15)
    assert proc.poll() is None  # the graph keeps it running, retrying
    assert listener.diag["connected"] is False
    sentence = "cannot open serial port /dev/no-such-joystick: no such device (is the joystick plugged in?)"
    assert listener.diag["last_diagnostic"].startswith(sentence)
    log = err.read_text()
    assert log.count(sentence) == 1 and "Traceback" not in log  # said once, not once per retry
    # a URL scheme pyserial does not know can never work: the node stops at once and says so
    out = graph.run("run", "joystick", "port=bogus://x")
    assert out.returncode == 1
    assert out.stderr.strip().splitlines()[-1] == (
        "facesculpt: joystick: port 'bogus://x': pyserial has no bogus:// handler "
        "(use a device path, loop://, socket://, rfc2217://, ...)")


class LoopDevice:
    """Writes into the node's own loop:// port (pyserial's loopback: what is written is read back)."""

    def __init__(self, node):
        self.node = node

    def write(self, data: bytes):
        port = self.node.reader.serial
        if port is None:
            raise OSError("not open yet")
        port.write(data)


def test_grab_takes_the_landmark_nearest_the_face_roi_centre(graph):
    """In-process over loop://: the grab button presses the landmark nearest the centre of the
    fitted face's ROI; with no face yet it says so in one sentence and presses nothing."""
    node = graph.node(JoystickNode(params={"port": "loop://"}))
    listener = Listener(graph)
    device = LoopDevice(node)

    def spin(predicate, timeout=5.0):  # two nodes in this process: spin both
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            node.spin_once(0.01)
            listener.node.spin_once(0.01)
            if predicate():
                return True
        return False
    listener.wait = spin
    listener.sync(device)
    listener.events.clear()
    device.write(b"0 0 0 1\n")
    assert spin(lambda: node.counters.get("grab_failed", 0) == 1 and listener.events)
    assert node.diagnostics()["last_diagnostic"] == "cannot grab: no fitted face seen yet (face/state and face/model)"
    assert [e.kind for e in listener.events] == ["buttons"]
    # a face: a grid of projected vertices, three landmarks; the ROI centre is at (200, 250)
    xs, ys = np.meshgrid(np.linspace(100, 300, 11), np.linspace(50, 450, 21))
    projected = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float32)
    V = len(projected)
    vertices = np.zeros((V, 3), np.float32)
    centre = int(np.argmin(np.linalg.norm(projected - [200, 250], axis=1)))
    node.on_model(FaceModel(model_id="grid", vertices=vertices, triangles=np.zeros((0, 3), np.int32),
                            landmark_names=["chin", "nose_tip", "forehead"],
                            landmark_vertices=np.array([V - 6, centre + 11, 5], np.int32)))
    node.on_state(FaceState(model_id="grid", vertices=vertices, projected=projected))
    listener.events.clear()
    device.write(b"0 0 0 0\n0 0 0 1\n")
    assert spin(lambda: any(e.kind == "press" for e in listener.events))
    assert [e.landmark for e in listener.events if e.kind == "press"] == ["nose_tip"]
