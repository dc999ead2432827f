"""`facesculpt demo`: the main job on the embedded default input.

Runs facesculpt/launch/demo.yaml (the embedded face photo under a moving virtual camera ->
landmarks -> fitter -> deformer <- scripted edits -> renderer -> video file), all
headless, as separate processes. Beside the graph, an in-process listener keeps
camera frames and rendered frames by stamp and every node's diagnostics, and
writes into the output folder:

* ``demo.mp4``          the rendered video (written by the renderer node),
* ``before_after.png``  the last rendered frame beside the camera frame it was made from,
* ``timing.md`` / ``timing.json``  per-node stage times (mean ms) and rates.
"""

from __future__ import annotations

import collections
import json
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from facesculpt.msgs import Diagnostics, Image
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVERY_MESSAGE


def register(sub) -> None:
    p = sub.add_parser("demo", help="the main job: the whole graph on an embedded face, with scripted edits",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="facesculpt-demo", help="output folder (default ./facesculpt-demo)")
    p.add_argument("--frames", type=int, default=180, help="camera frames to play (default 180, 12 s at 15 fps)")
    p.add_argument("--model", default="facemesh", help="face model: facemesh (default) or a .npz file")
    p.add_argument("--source", default="embedded", help="camera source instead of the embedded photo")
    p.set_defaults(func=cmd_demo)


class DemoListener(Node):
    """Keeps recent camera frames, the rendered frames, and all diagnostics."""

    NAME = "_demo_listener"

    def setup(self):
        self.frames: collections.OrderedDict[int, np.ndarray] = collections.OrderedDict()
        self.last_pair: tuple[np.ndarray, np.ndarray] | None = None  # (camera frame, its rendering)
        self.rendered = 0
        self.stages: dict[str, dict[str, list[float]]] = collections.defaultdict(lambda: collections.defaultdict(list))
        self.rates: dict[str, dict[str, float]] = {}
        self.subscribe("camera/image", Image, self.on_camera, qos=EVERY_MESSAGE)
        self.subscribe("render/image", Image, self.on_render, qos=EVERY_MESSAGE)
        self.subscribe("diagnostics", Diagnostics, self.on_diagnostics, qos=EVERY_MESSAGE)

    def on_camera(self, msg: Image):
        self.frames[msg.stamp] = np.array(msg.image)
        while len(self.frames) > 90:
            self.frames.popitem(last=False)

    def on_render(self, msg: Image):
        self.rendered += 1
        before = self.frames.get(msg.stamp)
        if before is not None and before.shape == msg.image.shape:
            self.last_pair = (before, np.array(msg.image))

    def on_diagnostics(self, msg: Diagnostics):
        if msg.node.startswith("_"):
            return
        for stage, ms in (msg.values.get("stages_ms") or {}).items():
            self.stages[msg.node][stage].append(float(ms))
        rates = {t: r for t, r in (msg.values.get("rate_hz") or {}).items() if r}
        if rates:
            self.rates[msg.node] = rates


def before_after(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """The two frames side by side with labels (BGR)."""
    out = np.concatenate([before, after], axis=1).copy()
    for x, text in ((10, "before"), (before.shape[1] + 10, "after")):
        cv2.putText(out, text, (x, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (0, 0, 0), 4, cv2.LINE_AA)
        cv2.putText(out, text, (x, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 255), 2, cv2.LINE_AA)
    return out


def timing_table(listener: DemoListener) -> tuple[str, dict]:
    rows, data = ["| node | stage | mean ms |", "| --- | --- | --- |"], {}
    for node in sorted(listener.stages):
        for stage, values in sorted(listener.stages[node].items()):
            mean = float(np.mean(values))
            data.setdefault(node, {})[stage] = round(mean, 3)
            rows.append(f"| {node} | {stage} | {mean:.2f} |")
    rows += ["", "| node | input | rate Hz |", "| --- | --- | --- |"]
    for node, rates in sorted(listener.rates.items()):
        for topic, rate in sorted(rates.items()):
            rows.append(f"| {node} | {topic} | {rate:.1f} |")
    return "\n".join(rows) + "\n", {"stages_ms": data, "rates_hz": listener.rates}


def cmd_demo(args) -> int:
    from facesculpt.nodes import node_class
    from facesculpt.paths import launch_file
    from facesculpt.runtime.launcher import Launcher, load_launch

    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    video = out / "demo.mp4"
    # The listener below is a third camera/image subscriber: the camera waits for landmarks and
    # renderer too, or its first frame could go out before landmarks listens (and, in lockstep, be
    # waited for until camera.ack_timeout_s).
    specs = load_launch(launch_file("demo"), [
        f"camera.max_frames={args.frames}", f"camera.source={args.source}",
        f"fitter.model={args.model}", f"renderer.output={video}", "camera.wait_subscribers=3",
    ], node_class=node_class)
    launcher = Launcher(specs, status=lambda line: print(line, flush=True))
    launcher.start_master()  # the listener needs it before the nodes start
    master_proc, launcher.master_proc = launcher.master_proc, None  # stopped after the listener
    listener = DemoListener()
    listener.start()
    stop = threading.Event()

    def spin():
        while not stop.is_set():
            listener.spin_once(0.05)
    thread = threading.Thread(target=spin, name="demo-listener", daemon=True)
    thread.start()
    try:
        code = launcher.run()
    finally:
        time.sleep(0.3)
        stop.set()
        thread.join(2)
        listener.close()
        if master_proc is not None:
            master_proc.terminate()
            master_proc.wait(5)
    if listener.last_pair is None:
        raise RuntimeError(f"no rendered frame came out of the graph ({listener.rendered} rendered); "
                           "run `facesculpt setup` if the networks are missing, or see the log above")
    before, after = listener.last_pair
    cv2.imwrite(str(out / "before_after.png"), before_after(before, after))
    table, data = timing_table(listener)
    (out / "timing.md").write_text(table)
    (out / "timing.json").write_text(json.dumps(data, indent=1))
    print("\n" + table)
    print(f"wrote {video.name} ({listener.rendered} frames rendered), before_after.png, timing.md in {out}")
    return code
