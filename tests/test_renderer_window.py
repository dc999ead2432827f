"""The renderer's window under a real X server (Xvfb): it opens at the frame's size, shows the
composited frame (checked on a screenshot), and mouse/key events sent with xdotool come back
as input events in frame pixel coordinates. Needs the Debian packages xvfb, xdotool and
x11-apps (xwd, for screenshots; ImageMagick's `import` also works); skips without them."""

from __future__ import annotations

import os
import select
import shutil
import signal
import subprocess
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from benchmarks.renderer_scene import place_marked, psnr, read_frames

TOOLS = ("Xvfb", "xdotool", "xdpyinfo")


@pytest.fixture(scope="module")
def display():
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if not (shutil.which("xwd") or shutil.which("import")):
        missing.append("xwd")
    if missing:
        pytest.skip(f"needs {', '.join(missing)} (apt-get install xvfb xdotool x11-utils x11-apps)")
    # -displayfd: Xvfb picks a free display number itself and writes it to the pipe, so test
    # sessions running side by side never share (or race for) one.
    read_fd, write_fd = os.pipe()
    proc = subprocess.Popen(["Xvfb", "-displayfd", str(write_fd), "-screen", "0", "1920x1080x24", "-nolisten", "tcp"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, pass_fds=(write_fd,))
    os.close(write_fd)
    with os.fdopen(read_fd) as pipe:
        ready = select.select([pipe], [], [], 20.0)[0]
        number = pipe.readline().strip() if ready else ""  # written once the server is ready; "" if it died
    assert number.isdigit(), f"Xvfb did not start (exit status {proc.poll()})"
    # Seen on CI: a client started right after -displayfd reported the number could not open the
    # display; wait until one can (xdpyinfo connects and exits 0).
    deadline = time.monotonic() + 20.0
    while subprocess.run(["xdpyinfo"], env=dict(os.environ, DISPLAY=f":{number}"),
                         capture_output=True).returncode != 0:
        assert time.monotonic() < deadline and proc.poll() is None, f"display :{number} does not accept clients"
        time.sleep(0.2)
    yield f":{number}"
    proc.terminate()
    proc.wait(5)


def xtool(display, *args, capture=False):
    env = dict(os.environ, DISPLAY=display)
    return subprocess.run(args, env=env, check=True, capture_output=True, timeout=20).stdout if capture else \
        subprocess.run(args, env=env, check=True, timeout=20)


def decode_xwd(data: bytes) -> np.ndarray:
    """A (H, W, 3) uint8 BGR image from an X window dump (xwd) of a 24/32-bit TrueColor window."""
    header = np.frombuffer(data[:100], ">u4")
    header_size, version, pixmap_format, depth, width, height = (int(v) for v in header[:6])
    byte_order, bits_per_pixel, bytes_per_line = int(header[7]), int(header[11]), int(header[12])
    red_mask, green_mask, blue_mask, ncolors = int(header[14]), int(header[15]), int(header[16]), int(header[19])
    assert version == 7 and pixmap_format == 2 and bits_per_pixel == 32, "unsupported xwd dump"
    start = header_size + 12 * ncolors
    rows = np.frombuffer(data[start:start + bytes_per_line * height], np.uint8).reshape(height, bytes_per_line)
    pixels = rows[:, :4 * width].copy().view("<u4" if byte_order == 0 else ">u4").reshape(height, width)

    def channel(mask):
        shift = (mask & -mask).bit_length() - 1
        return ((pixels & mask) >> shift).astype(np.uint8)

    return np.dstack([channel(blue_mask), channel(green_mask), channel(red_mask)])


def screenshot(display, window_id: str) -> np.ndarray:
    """The window's pixels as the X server has them, (H, W, 3) uint8 BGR (xwd, else ImageMagick)."""
    if shutil.which("xwd"):
        return decode_xwd(xtool(display, "xwd", "-silent", "-id", window_id, capture=True))
    png = xtool(display, "import", "-window", window_id, "png:-", capture=True)
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)


class WindowShots(list):
    """Screenshots of window ``wid``, newest last: :meth:`shows` takes one and asks ``predicate``
    of it; False while the window is being mapped or resized (xwd fails with BadMatch)."""

    def __init__(self, display, wid: str):
        super().__init__()
        self.display, self.wid = display, wid

    def shows(self, predicate) -> bool:
        try:
            self.append(screenshot(self.display, self.wid))
        except subprocess.CalledProcessError:
            return False
        return predicate(self[-1])


def poll_until(window, predicate, timeout=5.0):
    events = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        events += window.poll()
        if predicate(events):
            break
        time.sleep(0.01)
    return events


def test_window_shows_the_frame_and_reports_input_in_frame_pixels(display, data_dir, monkeypatch):
    monkeypatch.setenv("DISPLAY", display)
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.renderer import Compositor
    from facesculpt.nodes.renderer.window import Window, draw_overlay

    frame = read_frames(data_dir, "s18")[0]
    H, W = frame.shape[:2]
    title = f"facesculpt-test-{os.getpid()}"
    window = Window(W, H, title)
    try:
        # The compositor draws with the window's own context, as in the node.
        pose = place_marked(load_model("sfm"), "s18")
        comp = Compositor(W, H, ctx=window.ctx)
        out = comp.render(frame, pose.fitted, pose.projected, pose.triangles, pose.fitted)
        for _ in range(3):
            window.show(out)
            window.poll()
        wid = xtool(display, "xdotool", "search", "--name", title, capture=True).split()[0].decode()
        shot = screenshot(display, wid)
        assert shot.shape == (H, W, 3)               # a real window at the frame's size
        assert psnr(shot, frame) > 40                # showing the composited frame
        # An overlay drawn into the frame shows up too (handles in red).
        nose = pose.projected[pose.landmarks["nose_tip"]]
        window.show(draw_overlay(out, ["42 fps"], points=nose[None]))
        window.poll()
        shot = screenshot(display, wid)
        x, y = np.round(nose).astype(int)
        ring = shot[y - 7:y + 8, x - 7:x + 8].reshape(-1, 3).astype(int)
        assert ((ring[:, 2] > 180) & (ring[:, 1] < 80)).sum() > 10

        # A drag on the nose: press, drags, release, at the frame pixels xdotool moved to.
        start, end = (int(x), int(y)), (int(x) + 30, int(y) - 10)
        xtool(display, "xdotool", "mousemove", "--window", wid, *map(str, start), "mousedown", "1",
              "mousemove", "--window", wid, str(start[0] + 15), str(start[1] - 5),
              "mousemove", "--window", wid, *map(str, end), "mouseup", "1")
        events = poll_until(window, lambda ev: any(e["kind"] == "release" for e in ev))
        kinds = [e["kind"] for e in events]
        assert kinds[0] == "press" and kinds[-1] == "release" and "drag" in kinds
        assert abs(events[0]["x"] - start[0]) <= 1 and abs(events[0]["y"] - start[1]) <= 1
        assert abs(events[-1]["x"] - end[0]) <= 1 and abs(events[-1]["y"] - end[1]) <= 1

        # Keys: R resets, U undoes, S saves the edits as a preset.
        xtool(display, "xdotool", "key", "--window", wid, "r", "u", "s")
        events = poll_until(window, lambda ev: len(ev) >= 3)
        assert [e.get("command") for e in events] == ["reset", "undo", "save_preset"]
        assert events[2]["argument"].endswith(".json")

        # A window twice the frame's size still reports frame pixels.
        import glfw

        glfw.set_window_size(window.handle, 2 * W, 2 * H)
        poll_until(window, lambda ev: glfw.get_window_size(window.handle) == (2 * W, 2 * H), 3)
        window.show(out)
        xtool(display, "xdotool", "mousemove", "--window", wid, str(2 * start[0]), str(2 * start[1]),
              "click", "1")
        events = poll_until(window, lambda ev: any(e["kind"] == "release" for e in ev))
        assert abs(events[0]["x"] - start[0]) <= 1 and abs(events[0]["y"] - start[1]) <= 1
        comp.release()
    finally:
        window.close()


def _scene_feeder(model, pose, frame, preset_dir: Path | None = None):
    """A node that plays camera + fitter for the window graph: the frame and its posed face
    state at 15 Hz, the model latched; it keeps the input events it hears and how many
    input/events subscribers the renderer reports (its diagnostics). It can play the deformer
    too: publish a deformation (latched), and answer a save_preset event as the deformer does,
    with the absolute path under ``preset_dir`` as ``last_saved_preset`` in its diagnostics."""
    from facesculpt.msgs import Deformation, Diagnostics, FaceModel, FaceState, Image, InputEvent
    from facesculpt.runtime.node import Node
    from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE, LATCHED

    H, W = frame.shape[:2]

    class Feeder(Node):
        NAME = "window_feeder"
        DIAGNOSTICS_PERIOD_S = 0.3

        def setup(self):
            self.image_pub = self.advertise("camera/image", Image)
            self.state_pub = self.advertise("face/state", FaceState)
            self.model_pub = self.advertise("face/model", FaceModel, qos=LATCHED)
            self.deformation_pub = self.advertise("face/deformation", Deformation, qos=LATCHED)
            self.events = []
            self.saved_preset = None
            self.subscribe("input/events", InputEvent, self.on_event, qos=EVENTS)
            self.listeners = 0  # the renderer's input/events subscribers, from its diagnostics
            self.subscribe("diagnostics", Diagnostics, self.on_diagnostics, qos=EVERY_MESSAGE)
            self.timer(1 / 15, self.tick)

        def on_diagnostics(self, msg):
            if msg.node == "renderer":
                self.listeners = msg.values.get("subscribers", {}).get("input/events", 0)

        def on_event(self, msg):
            self.events.append(msg)
            if msg.kind == "command" and msg.command == "save_preset" and preset_dir is not None:
                self.saved_preset = str((preset_dir / msg.argument).resolve())

        def diagnostics(self):
            values = super().diagnostics()
            if self.saved_preset:
                values["last_saved_preset"] = self.saved_preset
            return values

        def publish_pins(self, static):
            self.deformation_pub.publish(Deformation(
                stamp=1, model_id=model.model_id, displacement=np.zeros((len(model.mean), 3), np.float32),
                static=np.asarray(static, np.int32), version=1))

        def tick(self):
            stamp = time.time_ns()
            self.image_pub.publish(Image(stamp=stamp, image=frame, K=pose.K))
            self.state_pub.publish(FaceState(
                stamp=stamp, model_id=model.model_id, R=pose.R, t=np.zeros(3), scale=1.0, K=pose.K,
                vertices=pose.fitted.astype(np.float32), projected=pose.projected.astype(np.float32),
                image_size=[W, H], projection="perspective"))

        def publish_model(self):
            self.model_pub.publish(FaceModel(stamp=1, model_id=model.model_id,
                                             vertices=model.mean.astype(np.float32),
                                             triangles=model.triangles.astype(np.int32)))

    return Feeder()


@pytest.mark.slow
def test_drag_in_the_window_deforms_the_nose_through_the_deformer(display, graph, data_dir):
    """The graph: this test plays camera + fitter (real frame, posed SFM); the renderer (window)
    and the deformer run as real processes. A drag sent with xdotool on the nose reaches the
    deformer as input/events, and the window then shows a changed nose."""
    from facesculpt.nodes.fitter import load_model

    model = load_model("sfm")
    pose = place_marked(model, "s18")
    frame = read_frames(data_dir, "s18")[0]
    H, W = frame.shape[:2]

    title = f"facesculpt-graph-{os.getpid()}"
    graph.env["DISPLAY"] = display
    graph.spawn("run", "renderer", "window=true", "overlay=false", f"title={title}")
    graph.spawn("run", "deformer")
    feeder = graph.node(_scene_feeder(model, pose, frame))
    feeder.publish_model()
    found = []

    def window_up():
        if not found:
            # --onlyvisible: the window exists before it is mapped, and xwd fails on an unmapped one.
            r = subprocess.run(["xdotool", "search", "--onlyvisible", "--name", title],
                               env=dict(os.environ, DISPLAY=display), capture_output=True)
            found.extend(r.stdout.split())
        return bool(found)

    assert graph.spin_until(feeder, window_up, 40.0), "the renderer's window did not open"
    wid = found[0].decode()
    shots = WindowShots(display, wid)
    shows = shots.shows

    # No edit yet: the window shows the frame itself.
    assert graph.spin_until(feeder, lambda: shows(lambda s: s.shape == (H, W, 3) and psnr(s, frame) > 40), 20.0)
    before = shots[-1]

    # A press sent before the deformer has connected to the renderer would be lost (a slow start
    # under load): wait until the renderer counts both listeners (this feeder and the deformer).
    assert graph.spin_until(feeder, lambda: feeder.listeners == 2, 30.0), \
        f"the deformer did not connect to input/events ({feeder.listeners} listeners)"
    x, y = np.round(pose.projected[pose.landmarks["nose_tip"]]).astype(int)
    path = [(x + dx, y) for dx in (0, 8, 16, 24, 32)]
    args = ["mousemove", "--window", wid, str(path[0][0]), str(path[0][1]), "mousedown", "1"]
    for px, py in path[1:]:
        args += ["mousemove", "--window", wid, str(px), str(py), "sleep", "0.1"]
    args += ["mouseup", "1"]
    xtool(display, "xdotool", *args)
    assert graph.spin_until(feeder, lambda: any(e.kind == "release" for e in feeder.events), 10.0)
    kinds = [e.kind for e in feeder.events]
    assert kinds[0] == "press" and "drag" in kinds and kinds[-1] == "release"
    assert abs(feeder.events[0].x - x) <= 1 and abs(feeder.events[0].y - y) <= 1
    assert abs(feeder.events[-1].x - path[-1][0]) <= 1 and feeder.events[0].source == "window"
    # The deformer solves, the renderer draws the edit.
    patch = (slice(y - 25, y + 26), slice(x - 20, x + 45))
    changed = graph.spin_until(
        feeder, lambda: shows(lambda s: np.abs(s[patch].astype(int) - before[patch]).mean() > 8), 20.0)
    assert changed, "the nose did not change"
    after = shots[-1]
    # Far from the face nothing changed.
    assert np.array_equal(after[:, :300], before[:, :300])


def _visible_window(display, title: str) -> str:
    """The id of the visible window titled ``title``, "" while there is none."""
    # --onlyvisible: the window exists before it is mapped, and xwd fails on an unmapped one.
    r = subprocess.run(["xdotool", "search", "--onlyvisible", "--name", title],
                       env=dict(os.environ, DISPLAY=display), capture_output=True)
    return (r.stdout.split() or [b""])[0].decode()


def _panel_size(shot: np.ndarray, frame: np.ndarray) -> tuple[int, int]:
    """(rows, columns) of the top-left text panel in a screenshot: pixels the panel darkened to
    well under the frame's brightness, counted down the strip left of the letters and along the
    strip above them."""
    from facesculpt.nodes.renderer.overlay import MARGIN_PX

    strip = slice(MARGIN_PX + 1, 2 * MARGIN_PX)
    shot, frame = shot[:240].astype(float), frame[:240].astype(float)
    rows = shot[:, strip].mean(axis=(1, 2)) < 0.6 * frame[:, strip].mean(axis=(1, 2))
    cols = shot[strip].mean(axis=(0, 2)) < 0.6 * frame[strip].mean(axis=(0, 2))
    return int(rows.sum()), int(cols.sum())


@pytest.mark.slow
def test_pins_and_a_saved_preset_show_in_the_window(display, graph, data_dir, tmp_path):
    """The overlay in a real window: pinned vertices (Deformation.static) are drawn as yellow
    squares where the face shows them; S sends save_preset, the window says so at once, and
    when the deformer's diagnostics report the file (played here by the feeder) the renderer
    logs its absolute path and shows it for a few seconds."""
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.renderer.overlay import PIN_BGR

    model = load_model("sfm")
    pose = place_marked(model, "s18")
    frame = read_frames(data_dir, "s18")[0]
    title = f"facesculpt-pins-{os.getpid()}"
    graph.env["DISPLAY"] = display
    log = tmp_path / "renderer.txt"
    with open(log, "w") as out:
        graph.spawn("run", "renderer", "window=true", "overlay=true", f"title={title}",
                    stdout=out, stderr=subprocess.STDOUT)
    preset_dir = tmp_path / "presets-in-a-directory-with-a-long-name"  # the widest line of the overlay
    feeder = graph.node(_scene_feeder(model, pose, frame, preset_dir=preset_dir))
    feeder.publish_model()
    pins = [pose.landmarks[name] for name in ("nose_tip", "chin", "mouth_left")]
    feeder.publish_pins(pins)
    found = []
    assert graph.spin_until(feeder, lambda: found.append(_visible_window(display, title)) or found[-1], 40.0), \
        f"the renderer's window did not open: {log.read_text()}"
    wid = found[-1]
    shots = WindowShots(display, wid)
    shows = shots.shows

    def pinned(shot):
        hits = []
        for v in pins:
            x, y = np.round(pose.projected[v]).astype(int)
            patch = shot[y - 6:y + 7, x - 6:x + 7].reshape(-1, 3).astype(int)
            hits.append((np.abs(patch - PIN_BGR).max(axis=1) < 40).sum())
        return min(hits) >= 30  # a 9 x 9 px square at each pin, within a pixel or two
    assert graph.spin_until(feeder, lambda: shows(pinned), 20.0), "no pins drawn at the pinned vertices"
    rows_before, cols_before = _panel_size(shots[-1], frame)
    assert rows_before > 15 and cols_before > 200  # the fps and stage-time lines

    assert graph.spin_until(feeder, lambda: feeder.listeners == 1, 30.0)
    subprocess.run(["xdotool", "key", "--window", wid, "s"], env=dict(os.environ, DISPLAY=display), check=True)
    assert graph.spin_until(feeder, lambda: feeder.saved_preset is not None, 10.0), "no save_preset event"
    name = Path(feeder.saved_preset).name
    assert name.startswith("facesculpt-edits-") and name.endswith(".json")
    # At once a line more ("saving preset NAME"); once the deformer reports the file, its
    # absolute path (longer than any other line here): a wider panel.
    assert graph.spin_until(feeder, lambda: shows(lambda s: _panel_size(s, frame)[0] > rows_before + 10), 10.0), \
        "no notice line in the window after S"
    assert graph.spin_until(feeder, lambda: shows(lambda s: _panel_size(s, frame)[1] > cols_before + 50), 10.0), \
        "the saved preset's path is not shown"
    text = log.read_text()
    assert f"asked the deformer to save the edits as preset {name}" in text
    assert f"saved the preset as {feeder.saved_preset}" in text, text
    # A few seconds later the notice is gone again.
    assert graph.spin_until(feeder, lambda: shows(lambda s: _panel_size(s, frame)[0] <= rows_before + 3), 15.0)


def _launch_window_graph(graph, display, tmp_path, title: str, **renderer_params):
    """`facesculpt launch` of camera (embedded photo, 15 fps) + renderer (window, marked
    respawn, ``renderer_params``), output to a log file; returns (launcher, log path, env) once
    the renderer's window is visible and has shown a few frames."""
    import yaml

    launch = tmp_path / "window.yaml"
    launch.write_text(yaml.safe_dump({"nodes": [
        {"name": "camera", "node": "camera", "params": {"source": "embedded", "fps": 15.0}},
        {"name": "renderer", "node": "renderer", "respawn": True,
         "params": {"window": True, "overlay": False, "title": title, **renderer_params}},
    ]}))
    graph.env["DISPLAY"] = display
    log = tmp_path / "launch.txt"
    with open(log, "w") as out:
        proc = graph.spawn("launch", str(launch), stdout=out, stderr=subprocess.STDOUT)
    env = dict(os.environ, DISPLAY=display)
    deadline = time.monotonic() + 60
    wid = b""
    while not wid:
        assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
        wid = subprocess.run(["xdotool", "search", "--onlyvisible", "--name", title], env=env,
                             capture_output=True).stdout.split(b"\n")[0]
        time.sleep(0.2)
    time.sleep(1.0)  # a few frames shown
    return proc, log, env


def _press_q_until(env, title: str, done, timeout: float = 30.0) -> None:
    """Send Q to every visible window titled ``title`` until ``done()``: the window may still be
    settling (mapped, resized), and an id taken once may already be stale."""
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        subprocess.run(["xdotool", "search", "--onlyvisible", "--name", title, "key", "--window", "%@", "q"],
                       env=env, capture_output=True, timeout=20)
        time.sleep(0.5)


@pytest.mark.slow
def test_q_in_the_window_stops_the_whole_graph(display, graph, tmp_path):
    """Q in the window ends the renderer with the stop-the-graph status; the launcher stops every
    node (the renderer is marked respawn, and does not come back) and exits 0."""
    title = f"facesculpt-quit-{os.getpid()}"
    proc, log, env = _launch_window_graph(graph, display, tmp_path, title)
    _press_q_until(env, title, lambda: proc.poll() is not None)
    assert proc.wait(10) == 0, log.read_text()
    text = log.read_text()
    assert "[renderer] asked the graph to stop" in text and text.count("[renderer] running") == 1, text


@pytest.mark.slow
def test_q_with_close_node_stops_only_the_renderer(display, graph, tmp_path):
    """close: node in the launch file: Q ends the renderer alone, with EXIT_NODE_CLOSED, which the
    launcher does not respawn (it is marked respawn) nor count as a failure; the camera runs on
    until the launcher is stopped, and launch then exits 0."""
    from facesculpt.msgs import Image
    from facesculpt.runtime.node import Node

    title = f"facesculpt-close-{os.getpid()}"
    proc, log, env = _launch_window_graph(graph, display, tmp_path, title, close="node")
    _press_q_until(env, title, lambda: "[renderer] closed by the user" in log.read_text())
    text = log.read_text()
    assert "[renderer] closed by the user (its window); not respawning" in text, text
    assert "stopping the renderer (close=node" in text and "asked the graph to stop" not in text, text
    # The rest of the graph runs on: the camera still publishes, the renderer stays gone.
    frames = []
    watcher = graph.node(Node(name="close_watcher"))
    watcher.subscribe("camera/image", Image, frames.append)
    assert graph.spin_until(watcher, lambda: len(frames) >= 5, 20.0), log.read_text()
    assert proc.poll() is None, log.read_text()
    assert not subprocess.run(["xdotool", "search", "--onlyvisible", "--name", title], env=env,
                              capture_output=True).stdout.strip()
    proc.send_signal(signal.SIGINT)
    assert proc.wait(10) == 0, log.read_text()
    text = log.read_text()
    assert text.count("[renderer] running") == 1 and "respawning" not in text.replace("not respawning", ""), text
