"""The serial joystick node: ``facesculpt run joystick port=/dev/ttyACM0`` -> ``input/events``.

Reads the line protocol of :mod:`.joystick_protocol` (``X Y Z BUTTONS`` per line) from a serial device
or any pyserial URL (``loop://``, ``socket://host:port``, ``rfc2217://host:port``). A reader
thread owns the port: it opens it, reads, and when the device disappears closes it and
reopens it with exponential backoff (``reconnect_min_s`` doubling up to ``reconnect_max_s``),
so a joystick unplugged and plugged back resumes without a restart. The node's thread maps
samples to events (:class:`.joystick_protocol.JoystickMapper`): deadzone and speed turn the axes into a
model-space velocity (mm/s) that moves the grabbed handle; the grab button presses the
landmark nearest the centre of the fitted face's ROI (or ``grab_landmark``), the release
button releases it, the reset button sends ``command reset``; the pose button toggles pose
mode, where the axes turn the head (``pose`` events, ``pose_speed_deg_s`` at full deflection).

Diagnostics counters: ``lines`` (valid samples), ``malformed`` (skipped lines), ``connects``,
``disconnects``, ``open_failures``, ``events``, ``grab_failed``; ``connected`` and
``last_diagnostic`` (one sentence) are in the diagnostics values too.
"""

from __future__ import annotations

import collections
import errno
import importlib
import threading
import time

from facesculpt.geometry import axes_velocity
from facesculpt.geometry.axes_velocity import DEADZONE, DEADZONE_RANGE, SPEED_MM_S, SPEED_MM_S_RANGE
from facesculpt.msgs import FaceModel, FaceState, InputEvent
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import Param

from .face_targets import InputError, nearest_landmark, roi_centre
from .joystick_protocol import JoystickMapper, LineSplitter, ProtocolError, axis_signs, parse_line


def describe_open_error(port: str, exc: Exception) -> str:
    """One sentence for a port that would not open."""
    code = getattr(exc, "errno", None)
    if code == errno.ENOENT:
        why = "no such device (is the joystick plugged in?)"
    elif code == errno.EACCES:
        why = "permission denied (is the user in the dialout group?)"
    elif code == errno.EBUSY:
        why = "the device is busy (another program has it open)"
    else:
        why = str(exc)
    return f"cannot open serial port {port}: {why}"


def check_port(port: str) -> None:
    """ValueError for a port that can never open: empty, or a URL scheme pyserial does not know."""
    if not port.strip():
        raise ValueError("joystick: give the serial port, e.g. port=/dev/ttyACM0 or port=socket://127.0.0.1:7000")
    scheme, sep, _ = port.partition("://")
    if sep:
        try:
            importlib.import_module(f"serial.urlhandler.protocol_{scheme}")
        except ImportError:
            raise ValueError(f"joystick: port {port!r}: pyserial has no {scheme}:// handler "
                             "(use a device path, loop://, socket://, rfc2217://, ...)") from None


class SerialReader(threading.Thread):
    """Owns the port: open (with backoff), read, split and parse lines, reopen when lost.

    Appends ``(t_monotonic, kind, payload)`` to ``self.out``: kind ``sample`` (a Sample),
    ``malformed`` (the reason), ``connected`` / ``lost`` / ``open_failed`` (a sentence)."""

    def __init__(self, port: str, baudrate: int, min_s: float, max_s: float):
        super().__init__(name="joystick-serial", daemon=True)
        self.port = port
        self.baudrate = baudrate
        self.min_s = min_s
        self.max_s = max_s
        self.out: collections.deque = collections.deque()
        self.stopping = threading.Event()
        self.serial = None

    def run(self) -> None:
        import serial

        delay = self.min_s
        while not self.stopping.is_set():
            try:
                self.serial = serial.serial_for_url(self.port, baudrate=self.baudrate, timeout=0.05)
            except (serial.SerialException, OSError, ValueError) as exc:
                self.out.append((time.monotonic(), "open_failed", describe_open_error(self.port, exc)))
                self.stopping.wait(delay)
                delay = min(delay * 2.0, self.max_s)
                continue
            delay = self.min_s
            self.out.append((time.monotonic(), "connected", f"connected to {self.port}"))
            try:
                self._read(self.serial)
            except (serial.SerialException, OSError) as exc:
                if not self.stopping.is_set():
                    self.out.append((time.monotonic(), "lost", f"lost serial port {self.port} ({exc})"))
            finally:
                try:
                    self.serial.close()
                except Exception:  # closing a vanished device may fail; it is gone either way
                    pass
                self.serial = None

    def _read(self, port) -> None:
        splitter = LineSplitter()
        while not self.stopping.is_set():
            data = port.read(max(1, port.in_waiting))  # waits up to the timeout for the first byte
            if not data:
                continue
            t = time.monotonic()
            for line in splitter.feed(data):
                if line is None:
                    self.out.append((t, "malformed", "line too long"))
                    continue
                try:
                    sample = parse_line(line)
                except ProtocolError as exc:
                    self.out.append((t, "malformed", str(exc)))
                    continue
                if sample is not None:
                    self.out.append((t, "sample", sample))

    def stop(self) -> None:
        self.stopping.set()


class JoystickNode(Node):
    """Serial joystick: `X Y Z BUTTONS` lines -> input/events (move, press, release, reset)."""

    NAME = "joystick"
    TOPICS = ("input/events", "face/model", "face/state")
    PARAMS = {
        "port": Param("", "device path or pyserial URL (loop://, socket://host:port, rfc2217://host:port)"),
        "baudrate": Param(115200, "serial speed, bit/s", range=(50, 4000000)),
        "deadzone": Param(DEADZONE, "fraction of full deflection read as 0", range=DEADZONE_RANGE),
        "speed_mm_s": Param(SPEED_MM_S, "model-space mm/s of the handle at full deflection", range=SPEED_MM_S_RANGE),
        "invert": Param("", "axes to invert, e.g. \"y\" or \"xz\""),
        "grab_button": Param(0, "bit of BUTTONS that grabs (press) the landmark nearest the face ROI centre; -1: none",
                             range=(-1, 30)),
        "release_button": Param(1, "bit that releases it; -1: none", range=(-1, 30)),
        "reset_button": Param(2, "bit that sends `command reset`; -1: none", range=(-1, 30)),
        "pose_button": Param(3, "bit that toggles pose mode: the axes turn the head (x yaw, y pitch, z roll) instead "
                                "of moving the handle; -1: none", range=(-1, 30)),
        "pose_speed_deg_s": Param(30.0, "pose mode: degrees/s of the head's turn at full deflection",
                                  range=(0.1, 360.0)),
        "grab_landmark": Param("", "grab this landmark instead of the nearest one"),
        "handle": Param(1, "pointer id of the joystick's handle (the mouse is 0)", range=(0, None)),
        "max_dt_s": Param(0.25, "longest interval one sample's velocity is applied over, s", range=(0.001, 10.0)),
        "reconnect_min_s": Param(0.1, "first retry after the device disappears, s; doubles each time",
                                 range=(0.001, 60.0)),
        "reconnect_max_s": Param(2.0, "longest wait between retries, s (>= reconnect_min_s)", range=(0.001, 600.0)),
        "poll_s": Param(0.005, "how often the node's thread takes the reader's samples, s", range=(0.001, 1.0)),
    }

    def setup(self):
        p = self.params
        check_port(p.port)
        if not (p.reconnect_min_s > 0 and p.reconnect_max_s >= p.reconnect_min_s):
            raise ValueError("joystick: need 0 < reconnect_min_s <= reconnect_max_s")
        self.mapper = JoystickMapper(
            velocity=lambda axes: axes_velocity(axes, p.speed_mm_s, p.deadzone),
            signs=axis_signs(p.invert), grab_button=p.grab_button, release_button=p.release_button,
            reset_button=p.reset_button, handle=p.handle, max_dt_s=p.max_dt_s, pose_button=p.pose_button,
            pose_velocity=lambda axes: axes_velocity(axes, p.pose_speed_deg_s, p.deadzone))
        self.events = self.advertise("input/events", InputEvent)
        self.subscribe("face/model", FaceModel, self.on_model)
        self.subscribe("face/state", FaceState, self.on_state)
        self.model: FaceModel | None = None
        self.state: FaceState | None = None
        self.connected = False
        self.last_diagnostic = ""
        self.last_malformed = ""
        self.reader = SerialReader(p.port, p.baudrate, p.reconnect_min_s, p.reconnect_max_s)
        self.reader.start()
        self.timer(p.poll_s, self.on_poll)

    def on_model(self, msg: FaceModel):
        self.model = msg

    def on_state(self, msg: FaceState):
        if msg.vertices.shape[0] > 0:  # an empty state (no face in that frame) keeps the last fitted one
            self.state = msg

    def grab_target(self) -> str:
        """The landmark the grab button presses: ``grab_landmark``, else the one nearest the
        centre of the fitted face's ROI (from face/state and face/model)."""
        names = list(self.model.landmark_names) if self.model is not None else None
        if self.params.grab_landmark:
            if names is not None and self.params.grab_landmark not in names:
                raise InputError(f"grab_landmark {self.params.grab_landmark!r} is not a landmark of model "
                                 f"{self.model.model_id} (known: {', '.join(sorted(names)[:12])}, ...)")
            return self.params.grab_landmark
        if self.model is None or self.state is None or self.state.projected.shape[0] == 0:
            raise InputError("cannot grab: no fitted face seen yet (face/state and face/model)")
        if self.state.projected.shape[0] != self.model.vertices.shape[0]:
            raise InputError("cannot grab: face/state and face/model do not match yet")
        return nearest_landmark(self.state.projected, names, self.model.landmark_vertices,
                                roi_centre(self.state.projected))

    def say(self, sentence: str, counter: str | None = None, level: str = "warning") -> None:
        if counter:
            self.count(counter)
        if sentence != self.last_diagnostic:  # one line per new situation, not one per retry
            getattr(self.log, level)("%s", sentence)
        self.last_diagnostic = sentence

    def on_poll(self):
        out = self.reader.out
        while out:
            t, kind, payload = out.popleft()
            if kind == "sample":
                self.count("lines")
                try:
                    events = self.mapper.step(payload, t, self.grab_target)
                except InputError as exc:
                    events = exc.events
                    self.say(str(exc), "grab_failed")
                self.publish(events)
            elif kind == "malformed":
                self.count("malformed")
                self.last_malformed = payload
            elif kind == "connected":
                self.connected = True
                self.count("connects")
                self.mapper.interrupted()
                self.say(payload, level="info")
            elif kind == "lost":
                self.connected = False
                self.count("disconnects")
                self.mapper.interrupted()
                self.say(payload + f"; reconnecting (retry every <= {self.params.reconnect_max_s:g} s)")
            elif kind == "open_failed":
                self.count("open_failures")
                self.say(payload + f"; retrying every <= {self.params.reconnect_max_s:g} s")

    def publish(self, events: list[dict]) -> None:
        stamp = time.time_ns()
        for fields in events:
            self.events.publish(InputEvent(stamp=stamp, source=self.name, **fields))
            self.count("events")

    def diagnostics(self) -> dict:
        values = super().diagnostics()
        values.update(connected=self.connected, port=self.params.port, last_diagnostic=self.last_diagnostic,
                      last_malformed=self.last_malformed, grabbed=self.mapper.grabbed)
        return values

    def teardown(self):
        reader = getattr(self, "reader", None)
        if reader is not None:
            reader.stop()
            reader.join(1.0)


if __name__ == "__main__":
    JoystickNode.main()
