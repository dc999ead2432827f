"""The deformer node: ``input/events`` (queued) + ``face/state`` / ``face/model`` (latest) ->
``face/deformation``.

Events are queued on arrival and applied in rounds (every ``round_s``): the paper empties the
event queue each round, so any number of drags of a handle become one ARAP solve. Rounds run
on the node's own thread, independent of the frame rate; after a solve the rounds rest so that
solving takes at most ``solve_share`` of one core. Bad input (a miss, an unknown
landmark, NaN, a preset that does not fit) is counted in diagnostics and the last good
deformation stays. The ``preset`` param is checked at start (a missing or malformed file stops
the node with one sentence) and applied as soon as the first ``face/model`` arrives.

Several faces: each fitted face (``FaceState.face_id``) has its own edits on its own neutral
(:class:`FaceEditor`). A press or pin at a pixel goes to the face under it; drags, depth, moves
and joystick axes to the face of their pointer or selection; a landmark press, a preset and the
other commands to every face, unless the event names one (``InputEvent.face``). One
Deformation carries every face's displacement (``face_ids``, ``displacements``).

Pose edits (issue 18): a "pose" event adds to the pose offset of the face it names, else of the
selected face (the one last pressed), else of every face; ``reset`` and ``reset_pose`` clear it,
``undo`` leaves it. A pose change is rigid: it is published (``Deformation.pose`` / ``poses``)
without an ARAP solve.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from facesculpt.geometry.axes_velocity import DEADZONE, DEADZONE_RANGE, SPEED_MM_S, SPEED_MM_S_RANGE
from facesculpt.msgs import Deformation, FaceModel, FaceState, InputEvent
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import ConfigurationError, Param, option_params
from facesculpt.runtime.qos import EVENTS, LATCHED

from .deformer_options import DeformerOptions
from .errors import DeformerError
from .face_editor import FaceEditor
from .preset_format import STRENGTH_RANGE, find_preset, read_preset_file, scale_preset

MAX_PENDING_WITHOUT_MODEL = 10000
MAX_FACES = 16  # editors kept; the face edited longest ago is dropped first
MAX_REST_S = 0.1  # the longest wait solve_share puts after a solve (a preset's factorisation)
POINTER_KINDS = ("drag", "release", "depth", "move")
SELECTED_KINDS = ("depth", "move", "axes", "pose")


#: The :class:`DeformerOptions` fields the node takes as parameters (all of them).
DEFORMER_PARAMS = tuple(f.name for f in dataclasses.fields(DeformerOptions))


class DeformerNode(Node):
    """Turns input/events (drags of points of the face) into face/deformation (ARAP)."""

    NAME = "deformer"
    TOPICS = ("face/deformation", "face/model", "face/state", "input/events")
    PARAMS = {
        # the deformer's own options, declared once in DeformerOptions
        **option_params(DeformerOptions(), DEFORMER_PARAMS),
        "round_s": Param(0.005, "how often queued events are applied and solved, s", range=(0.001, 1.0)),
        "solve_share": Param(0.3, "share of one core the solves may take: after a solve of t seconds the "
                                  "next round waits t x (1/share - 1), at most 0.1 s (1: no wait)",
                             range=(0.05, 1.0)),
        "joystick_speed": Param(SPEED_MM_S, "axes events: mm/s of the handle at full deflection",
                                range=SPEED_MM_S_RANGE),
        "joystick_deadzone": Param(DEADZONE, "axes events: fraction of full deflection read as 0",
                                   range=DEADZONE_RANGE),
        "preset_dir": Param("", "where relative preset paths live (\"\": the current directory)"),
        "preset": Param("", "a preset applied when the first face/model arrives: a JSON file (relative to "
                            "preset_dir) or a shipped name (nose_longer, chin, cheeks); \"\": none"),
        "strength": Param(1.0, "multiplier of the offsets of every preset loaded (the preset param and "
                               "load_preset commands); 1: as saved", range=STRENGTH_RANGE),
    }

    def setup(self):
        # latched: a renderer that starts later still gets the current edit
        self.pub = self.advertise("face/deformation", Deformation, qos=LATCHED)
        self.subscribe("face/model", FaceModel, self.on_model)
        self.subscribe("face/state", FaceState, self.on_state)
        self.subscribe("input/events", InputEvent, self.on_event, qos=EVENTS)
        self.timer(self.params.round_s, self.on_round)
        self.model: FaceModel | None = None
        self.editors: dict[int, FaceEditor] = {}
        self.pending: list[InputEvent] = []
        self.pointer_face: dict[int, int] = {}  # pointer -> the face it pressed
        self.selected_face: int | None = None  # the face last pressed or selected
        self.displacements: dict[int, np.ndarray] = {}  # face -> last solved (V, 3) mm
        self.stamp = 0
        self.rest_until = 0.0  # time.monotonic() before which rounds wait (solve_share)
        self.last: Deformation | None = None  # last published (the last good deformation)
        self.initial_preset: dict | None = None
        self.last_diagnostic = ""  # the last problem of any face
        self.last_saved_preset = ""  # absolute path of the last preset written
        if self.params.preset:
            try:
                path = find_preset(self.params.preset, self.params.preset_dir)
                self.initial_preset = scale_preset(read_preset_file(path), self.params.strength)
            except DeformerError as exc:
                raise ConfigurationError(f"deformer: preset={self.params.preset!r}: {exc}") from None

    # -- the first face's editor (one face: the node's own state) ------------------------

    @property
    def editor(self) -> FaceEditor | None:
        """The editor of the face last edited, else of the lowest face id; None before a model."""
        if self.selected_face in self.editors:
            return self.editors[self.selected_face]
        return self.editors[min(self.editors)] if self.editors else None

    @property
    def stack(self):
        return None if self.editor is None else self.editor.stack

    @property
    def state(self) -> FaceState | None:
        return None if self.editor is None else self.editor.state

    @property
    def settle_rounds(self) -> int:
        return sum(e.settle_rounds for e in self.editors.values())

    @property
    def dirty(self) -> bool:
        return any(e.dirty for e in self.editors.values())

    @dirty.setter
    def dirty(self, value: bool) -> None:
        for e in self.editors.values():
            e.dirty = bool(value)

    # -- inputs --------------------------------------------------------------------------

    def _new_editor(self, face_id: int) -> FaceEditor:
        if len(self.editors) >= MAX_FACES:
            oldest = min(self.editors, key=lambda k: (k == self.selected_face, k))
            del self.editors[oldest]
            self.displacements.pop(oldest, None)
        preset = None if self.initial_preset is None else dict(self.initial_preset)
        editor = FaceEditor(face_id, self.params, self.count, self.stage, self.log, preset, self.params.preset)
        editor.report = lambda text: setattr(self, "last_diagnostic", text)
        editor.report_saved = lambda path: setattr(self, "last_saved_preset", path)
        self.editors[face_id] = editor
        if self.model is not None:
            editor.set_model(self.model, self.model.neutral_of(face_id))
        return editor

    def on_model(self, msg: FaceModel):
        if self.model is not None and msg.model_id == self.model.model_id and msg.version == self.model.version:
            return
        self.model = msg
        if not self.editors:
            self._new_editor(0)  # one face until the states say otherwise
        for face_id, editor in self.editors.items():
            editor.set_model(msg, msg.neutral_of(face_id))
        for face_id in [] if msg.face_ids is None else msg.face_ids.tolist():
            if face_id not in self.editors:
                self._new_editor(face_id)

    def on_state(self, msg: FaceState):
        if msg.vertices.shape[0] == 0:
            return  # an empty state (no face in that frame) keeps the last fitted one
        editor = self.editors.get(msg.face_id)
        if editor is None:
            if self.model is None:
                return
            editor = self._new_editor(msg.face_id)
        editor.remember(msg)

    def on_event(self, msg: InputEvent):
        self.pending.append(msg)

    # -- rounds --------------------------------------------------------------------------

    def on_round(self):
        if self.model is None or not self.editors:
            # Events wait (bounded) for the first face/model instead of being lost.
            if len(self.pending) > MAX_PENDING_WITHOUT_MODEL:
                self.count("events_without_model", len(self.pending) - MAX_PENDING_WITHOUT_MODEL)
                del self.pending[:-MAX_PENDING_WITHOUT_MODEL]
            return
        if time.monotonic() < self.rest_until:
            return  # the last solve's rest: events wait and are solved together next round
        events, self.pending = self.pending, []
        routed: dict[int, list[InputEvent]] = {k: [] for k in self.editors}
        for ev in events:
            self.stamp = ev.stamp or self.stamp
            for face_id in self._faces_of(ev):
                routed[face_id].append(ev)
        changed = False
        t0 = time.monotonic()
        for face_id, editor in self.editors.items():
            displacement = editor.round(routed.get(face_id, []))
            if displacement is not None:
                self.displacements[face_id] = displacement
                changed = True
            if editor.pose_changed:  # rigid: published as it is, nothing to solve
                editor.pose_changed = False
                changed = True
        if changed:
            self.publish()
        self._rest_after(time.monotonic() - t0)

    def _rest_after(self, spent_s: float) -> None:
        """Keep the rounds' solves within ``solve_share`` of one core. A drag solves every round
        while it moves and settles; with a large mesh and several edits those solves take CPU the
        frame path (fitter, renderer) needs on a small machine, and the frames' latency rises
        during drags (docs/results/live-graph.md, "The deformer rests between solves"). Waiting merges the drag's
        events into fewer solves."""
        share = self.params.solve_share
        self.rest_until = time.monotonic() + min(MAX_REST_S, spent_s * (1.0 / share - 1.0))

    def _faces_of(self, ev: InputEvent) -> list[int]:
        """The faces an event edits (see the module docstring)."""
        if ev.face >= 0:
            if ev.face not in self.editors:
                self.count("event_for_unknown_face")
                return []
            faces = [ev.face]
        elif ev.kind in POINTER_KINDS and ev.handle in self.pointer_face:
            faces = [self.pointer_face[ev.handle]]
        elif ev.kind in SELECTED_KINDS and not ev.landmark and self.selected_face in self.editors:
            faces = [self.selected_face]
        elif (ev.kind == "press" and not ev.landmark) or (ev.kind == "command" and ev.command == "toggle_static"):
            faces = self._face_under(ev)
        elif ev.kind == "command" and ev.command in ("save_preset", "select_edit") and self.editor is not None:
            faces = [self.editor.face_id]
        else:
            faces = list(self.editors)
        if ev.kind == "press" and faces:
            self.pointer_face[ev.handle] = faces[0]
            self.selected_face = faces[0]
        elif ev.kind == "release":
            self.pointer_face.pop(ev.handle, None)
        return faces

    def _face_under(self, ev: InputEvent) -> list[int]:
        """The face whose deformed mesh is nearest under the event's pixel; with one face, that
        face (its editor counts the miss)."""
        if len(self.editors) == 1 or not (np.isfinite(ev.x) and np.isfinite(ev.y)):
            return [next(iter(self.editors))] if len(self.editors) == 1 else []
        with self.stage("pick"):
            hits = {k: e.hit_distance(ev.x, ev.y) for k, e in self.editors.items()}
        hits = {k: d for k, d in hits.items() if d is not None}
        if not hits:
            self.count("pick_miss")
            self.last_diagnostic = f"pick_miss: pixel ({ev.x:.1f}, {ev.y:.1f}) is on no face"
            return []
        return [min(hits, key=hits.get)]

    def _displacement_of(self, face_id: int) -> np.ndarray:
        """(V, 3) mm the last solved displacement of a face; zeros before its first solve."""
        own = self.displacements.get(face_id)
        stack = self.editors[face_id].stack
        return own if own is not None or stack is None else np.zeros_like(stack.rest)

    def publish(self):
        editor = self.editor
        static, handles, roi, _ = editor.stack.anchors()
        roi = roi[roi < editor.stack.n]   # the model's vertices (a refined solve mesh has more)
        own = self._displacement_of(editor.face_id)
        several = len(self.editors) > 1
        # faces with a solve or a pose (a face turned before its first solve is listed with zeros)
        shown = {k: self._displacement_of(k) for k, e in self.editors.items()
                 if k in self.displacements or not e.pose.is_zero}
        faces = sorted(k for k, d in shown.items() if d is not None and len(d) == len(own))
        poses = {k: self.editors[k].pose.as_list() for k in faces}
        posed = any(any(p) for p in poses.values()) or not editor.pose.is_zero
        self.last = Deformation(
            stamp=self.stamp or time.time_ns(),
            model_id=self.model.model_id,
            displacement=own.astype(np.float32),
            static=static.astype(np.int32),
            handles=handles.astype(np.int32),
            roi=roi.astype(np.int32),
            version=sum(e.stack.version for e in self.editors.values() if e.stack is not None),
            face_id=editor.face_id,
            face_ids=np.array(faces, np.int32) if several else None,
            displacements=np.stack([shown[k] for k in faces]).astype(np.float32) if several else None,
            pose=np.array(editor.pose.as_list(), np.float32) if posed else None,
            poses=np.array([poses[k] for k in faces], np.float32).reshape(-1, 6) if several and posed else None,
        )
        self.pub.publish(self.last)

    def diagnostics(self) -> dict:
        values = super().diagnostics()
        values["last_diagnostic"] = self.last_diagnostic
        values["last_saved_preset"] = self.last_saved_preset
        values["faces"] = len(self.editors)
        return values
