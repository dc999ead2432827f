"""The scripted-gesture node: ``facesculpt run script script=examples/gestures/nose_pull.yaml``.

Plays a YAML gesture script (format: :mod:`.gesture_script`, docs/graph/scripts.md) as
``input/events``: presses at landmarks or pixels, drags by model-space millimetres or by
pixels over a duration, depth pushes, releases, waits, presets and commands — for demos, tests
and reproducible edits. Before the first step it waits (each optional) for a fitted face
(``face/state``, latest-only), for a subscriber of ``input/events`` (the deformer) and then
``start_delay_s``. Landmark names are checked against ``face/model`` before playing.

A script that cannot be read or compiled stops the node at start with one sentence naming the
file and line. A script that fails while playing (an unknown landmark, a pixel drag with no
face) logs one sentence, stops playing, and the node stays up; ``status`` and
``last_diagnostic`` in diagnostics say where it is.
"""

from __future__ import annotations

import time

from facesculpt.msgs import FaceModel, FaceState, InputEvent
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import Param
from facesculpt.runtime.qos import EVENTS

from .face_targets import InputError
from .gesture_script import ScriptError, ScriptPlayer, load_script


class ScriptNode(Node):
    """Plays a YAML gesture script as input/events."""

    NAME = "script"
    TOPICS = ("input/events", "face/state", "face/model")
    PARAMS = {
        "script": Param("", "path of the gesture script (YAML)"),
        "loop": Param(False, "start again when it ends (end the script with `command: reset` to undo each pass)"),
        "start_delay_s": Param(0.0, "after the waits below, before the first step, s", range=(0.0, 3600.0)),
        "wait_for_face": Param(True, "start only once a face/state with a fitted face has been seen"),
        "wait_subscribers": Param(1, "start only once this many nodes listen to input/events (0: don't wait)",
                                  range=(0, 1000)),
        "handle": Param(2, "pointer id of steps that name none (the mouse is 0, the joystick 1)", range=(0, None)),
        "exit_when_done": Param(False, "stop the node when the script has played (batch edits, tests)"),
        "poll_s": Param(0.005, "how often due events are sent, s", range=(0.001, 1.0)),
    }

    def setup(self):
        p = self.params
        if not p.script:
            raise ValueError("script: give the gesture script, e.g. script=examples/gestures/nose_pull.yaml")
        try:
            self.script = load_script(p.script, default_handle=p.handle)
        except ScriptError as exc:
            raise ValueError(str(exc)) from None
        self.events = self.advertise("input/events", InputEvent, qos=EVENTS)
        self.subscribe("face/state", FaceState, self.on_state)
        self.subscribe("face/model", FaceModel, self.on_model)
        self.state: FaceState | None = None
        self.model: FaceModel | None = None
        self.player: ScriptPlayer | None = None
        self.started_at = 0.0
        self.ready_at: float | None = None
        self.passes = 0
        self.status = "waiting"
        self.last_diagnostic = ""
        self.timer(p.poll_s, self.on_poll)
        self.log.info("script %s: %d events over %.2f s", p.script, len(self.script.actions), self.script.duration)

    def on_state(self, msg: FaceState):
        if msg.vertices.shape[0] > 0:
            self.state = msg

    def on_model(self, msg: FaceModel):
        self.model = msg

    # -- helpers -----------------------------------------------------------------------------------
    def locate(self, landmark: str) -> tuple[float, float]:
        """Pixel (x, y) of a landmark in the latest fitted face."""
        if self.state is None or self.model is None:
            raise InputError(f"cannot find landmark {landmark!r} in the image: no fitted face (face/state) yet")
        names = list(self.model.landmark_names)
        if landmark not in names:
            raise InputError(f"{landmark!r} is not a landmark of model {self.model.model_id}")
        v = int(self.model.landmark_vertices[names.index(landmark)])
        if v >= self.state.projected.shape[0]:
            raise InputError("face/state and face/model do not match yet")
        x, y = self.state.projected[v]
        return float(x), float(y)

    def check_landmarks(self) -> str | None:
        """One sentence when the script presses a landmark the face model does not have."""
        if self.model is None:
            return None
        names = set(self.model.landmark_names)
        for name, line in self.script.landmarks().items():
            if name not in names:
                known = ", ".join(sorted(n for n in names if not n.isdigit())[:16]) or ", ".join(sorted(names)[:16])
                return (f"{self.script.source} line {line}: {name!r} is not a landmark of model "
                        f"{self.model.model_id} (known: {known})")
        return None

    def fail(self, sentence: str) -> None:
        self.count("script_errors")
        self.last_diagnostic = sentence
        self.status = "stopped: " + sentence
        self.log.error("%s; the script stopped, the graph goes on", sentence)
        self.player = None
        self.ready_at = None
        if self.params.exit_when_done:
            self.shutdown()

    # -- the clock --------------------------------------------------------------------------------
    def _ready(self) -> bool:
        p = self.params
        if p.wait_for_face and self.state is None:
            self.status = "waiting for a fitted face (face/state)"
            return False
        if p.wait_subscribers > 0 and self.events.subscriber_count() < p.wait_subscribers:
            self.status = "waiting for a subscriber of input/events"
            return False
        return True

    def on_poll(self):
        if self.status.startswith(("stopped", "done")):
            return
        now = time.monotonic()
        if self.player is None:
            if not self._ready():
                return
            if self.ready_at is None:
                self.ready_at = now
            if now - self.ready_at < self.params.start_delay_s:
                self.status = "start delay"
                return
            problem = self.check_landmarks()
            if problem:
                self.fail(problem)
                return
            self.player = ScriptPlayer(self.script)
            self.started_at = now
            self.passes += 1
            self.log.info("playing %s (pass %d)", self.params.script, self.passes)
        t = now - self.started_at
        try:
            events = self.player.due(t, self.locate)
        except ScriptError as exc:
            self.fail(str(exc))
            return
        stamp = time.time_ns()
        for fields in events:
            if not self.events.publish(InputEvent(stamp=stamp, source=f"script:{self.name}", **fields), timeout_s=1.0):
                self.count("events_dropped")
            self.count("events")
        self.status = f"playing pass {self.passes}: {self.player.next}/{len(self.script.actions)} events"
        if self.player.finished(t):
            self.count("passes_done")
            if self.params.loop:
                self.player = None
                self.ready_at = now - self.params.start_delay_s  # loop straight on, no second delay
                return
            self.status = f"done ({self.passes} pass{'es' if self.passes > 1 else ''})"
            self.log.info("script %s done", self.params.script)
            if self.params.exit_when_done:
                self.shutdown()

    def run(self) -> int:
        """As Node.run; with ``exit_when_done``, exit status 1 when the script stopped on an error."""
        rc = super().run()
        return 1 if rc == 0 and self.params.exit_when_done and self.counters.get("script_errors") else rc

    def diagnostics(self) -> dict:
        values = super().diagnostics()
        values.update(status=self.status, last_diagnostic=self.last_diagnostic, script=self.params.script)
        return values


if __name__ == "__main__":
    ScriptNode.main()
