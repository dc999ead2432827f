"""The edits of one face: the deformer node keeps one :class:`FaceEditor` per fitted face.

An editor holds what a face's edit needs: the neutral mesh of that face (its :class:`EditStack`),
its latest fitted state (to turn pixels into the model), the pointers pressed on it, the handle
selected, joystick motion, and the solve's convergence. The node routes each input event to the
editors it concerns and asks each for a round (:meth:`FaceEditor.round`); sockets, timers and
publishing stay in the node. Bad input raises :class:`DeformerError`; a round that cannot be
solved rolls back and keeps the last good displacement.

The face's pose offset (issue 18, :class:`facesculpt.geometry.pose_offset.PoseOffset`) lives here
too: a "pose" event adds to it, ``reset`` and ``reset_pose`` clear it, a preset with a ``pose``
sets it, ``save_preset`` writes it. It is rigid, so changing it never solves ARAP: it sets
:attr:`FaceEditor.pose_changed` for the node to publish. ``undo`` leaves it as it is.
"""

from __future__ import annotations

import copy
import json
import time
from collections import OrderedDict
from pathlib import Path

import numpy as np

from facesculpt.geometry import axes_velocity, merge_deformation, project
from facesculpt.geometry.pose_offset import PoseOffset, parse_pose_offset
from facesculpt.msgs import FaceModel, FaceState, InputEvent

from .dragging import depth_delta, drag_delta
from .edits import EditStack
from .errors import DeformerError
from .picking import pick_vertex
from .preset_format import find_preset, pose_to_preset, preset_pose, read_preset_file, scale_preset

RECENT_STATES = 32  # fitted states kept by stamp (about a second of frames)

MAX_SETTLE_ROUNDS = 500  # idle rounds that may go on converging the last edit


class FaceEditor:
    """The edits of face ``face_id``. ``params``: the deformer node's params (roi_radius,
    roi_metric, grip, iterations, tolerance, acceleration, clamp_weights, joystick_speed,
    joystick_deadzone, preset_dir, strength); ``count(name, n=1)``, ``stage(name)`` and ``log``:
    the node's diagnostics; ``initial_preset``: a preset (dict, offsets scaled) put on the first
    neutral, named ``preset_name`` in the log."""

    def __init__(self, face_id: int, params, count, stage, log, initial_preset: dict | None = None,
                 preset_name: str = ""):
        self.face_id = int(face_id)
        self.params = params
        self.count, self.stage, self.log = count, stage, log
        self.model: FaceModel | None = None
        self.state: FaceState | None = None
        # The last few states by their frame's stamp: an event stamped with the frame it was made
        # on (a pinch seen in that frame) is turned into the model with that frame's pose, not the
        # newest one, which on a moving head or a busy machine may be frames away.
        self.recent_states: OrderedDict[int, FaceState] = OrderedDict()
        self.stack: EditStack | None = None
        self.pointers: dict[int, tuple[int, float, float]] = {}  # pointer -> (vertex, last x, last y)
        self.selected: int | None = None  # handle that depth/move/axes act on without a pointer
        self.velocity = np.zeros(3)  # model-space mm/s from joystick axes
        self.last_axes_at = time.monotonic()
        self.dirty = False
        self.settle_rounds = 0  # idle rounds left to converge the last solve
        self.last_diagnostic = ""  # the last problem, also handed to ``report`` (the node's)
        self.last_saved_preset = ""  # absolute path of the last preset written
        self.report = lambda text: None
        self.report_saved = lambda path: None
        # the last preset loaded (offsets scaled) and the edits it made: while the edits are still
        # those, a new neutral gets the preset again (its handles placed anew on that mesh)
        self.loaded: tuple[dict, str] | None = None
        self.initial_preset = initial_preset
        self.preset_name = preset_name
        self.pose = PoseOffset()  # the head's pose offset, published with the displacement
        self.pose_changed = False  # set when the pose changed; the node publishes and clears it

    def _bad(self, counter: str, exc: Exception):
        self.count(counter)
        self.last_diagnostic = f"{counter}: {exc}"
        self.report(self.last_diagnostic)
        self.log.warning("%s", self.last_diagnostic)

    # -- the neutral and the state ------------------------------------------------------------

    def set_model(self, msg: FaceModel, neutral: np.ndarray) -> None:
        """A new face/model: its triangles and landmark names with this face's ``neutral`` (V, 3)
        mm. The edits carry over (see :meth:`_carry_edits`)."""
        try:
            stack = EditStack(
                neutral,
                msg.triangles,
                msg.landmark_names,
                msg.landmark_vertices,
                roi_radius=self.params.roi_radius,
                roi_metric=self.params.roi_metric,
                grip=self.params.grip,
                min_solve_vertices=self.params.min_solve_vertices,
                iterations=self.params.iterations,
                tolerance=self.params.tolerance,
                acceleration=self.params.acceleration,
                clamp_weights=self.params.clamp_weights,
            )
        except DeformerError as exc:
            self._bad("bad_model", exc)
            return
        self._carry_edits(stack)
        same_topology = (self.model is not None and self.stack is not None and self.stack.n == stack.n
                         and np.array_equal(self.model.triangles, msg.triangles))
        if same_topology and self.stack.edits:
            # A refined neutral of the same mesh: the edit's shape barely changes, so the solver
            # starts from it (a few iterations) instead of from the rest mesh (many).
            stack.continue_from(self.stack)
        self.model, self.stack = msg, stack
        if not same_topology:
            # Vertex indices mean nothing on another mesh; on the same one (the face-mesh
            # neutral being refined) a drag in progress keeps its handle.
            self.pointers.clear()
            self.selected = None
        self.dirty = True

    def _carry_edits(self, stack: EditStack) -> None:
        """Put the edits on the new model's stack: the ``preset`` param on the first model; the
        last loaded preset again while the edits are still its own (its handles placed anew on
        this mesh); else the current edits (by landmark name, by vertex on the same topology, by
        position relative to the landmarks on another)."""
        first = self.initial_preset is not None
        if first:
            doc, self.initial_preset = self.initial_preset, None
        elif self.stack is None or not (self.stack.edits or self.stack.static):
            return
        elif self.loaded is not None and self.loaded[1] == _fingerprint(self.stack):
            doc = self.loaded[0]
        else:
            doc, self.loaded = self.stack.to_preset(), None
        try:
            stack.apply_preset(doc)
        except DeformerError as exc:
            self._bad("preset_rejected" if first else "edits_dropped_on_model_change", exc)
            return
        if first or self.loaded is not None:
            self.loaded = (doc, _fingerprint(stack))
        if first:
            self._set_pose(preset_pose(doc))
            self.count("preset_loaded")
            self.log.info("applied preset %s to face %d", self.preset_name, self.face_id)

    def round(self, events: list[InputEvent]) -> np.ndarray | None:
        """Apply this round's events (bad ones counted, the others kept), integrate joystick
        motion and solve when something changed or the last solve is still converging. Returns
        the new displacement (V, 3) mm, or None when nothing was solved (an idle round, or a
        solve rejected: the round's edits rolled back)."""
        if self.stack is None:
            return None
        if not events and not self.dirty and not np.any(self.velocity) and not self.settle_rounds:
            return None  # an idle round: nothing to apply, nothing to solve, nothing left to converge
        snapshot = (copy.deepcopy(self.stack.edits), set(self.stack.static))
        for ev in events:
            try:
                self.apply(ev)
            except DeformerError as exc:
                self._bad("bad_input", exc)
        self._integrate_axes()
        if not self.dirty and not self.settle_rounds:
            return None
        settling = not self.dirty
        self.dirty = False
        try:
            with self.stage("solve"):
                displacement = self.stack.solve()
        except DeformerError as exc:
            # e.g. an edit whose ROI holds no free vertex: roll the round back
            self.stack.edits, self.stack.static = snapshot
            self.settle_rounds = 0
            self._bad("solve_rejected", exc)
            return None
        # A drag gets a few iterations per round; once it stops, idle rounds go on iterating until
        # the mesh has converged (a bounded number of rounds), so the edit settles on the ARAP solution.
        if settling:
            self.count("settle_rounds")
        if self.stack.deformer.last_converged or self.params.tolerance <= 0:
            self.settle_rounds = 0
        elif settling:
            self.settle_rounds -= 1
        else:
            self.settle_rounds = MAX_SETTLE_ROUNDS
        return displacement

    def hit_distance(self, x: float, y: float) -> float | None:
        """Distance along the view ray to this face's deformed mesh under pixel (x, y), or None
        when the pixel is not on it (or there is no usable state): which face a press is on."""
        st = self.state
        if self.stack is None or st is None or st.vertices.shape[0] != self.stack.n:
            return None
        hit = pick_vertex(x, y, st.K, self._current_mesh(st), self.stack.triangles, st.projection)
        return None if hit is None else hit.distance

    # -- one event -----------------------------------------------------------------------

    def apply(self, ev: InputEvent):
        """Apply one input event to the edit stack (raises DeformerError on bad input)."""
        kind = ev.kind
        if kind == "press":
            self._press(ev)
        elif kind == "drag":
            self._drag(ev)
        elif kind == "release":
            self.pointers.pop(ev.handle, None)
        elif kind == "depth":
            v = self._target_vertex(ev)
            if not np.isfinite(ev.depth):
                raise DeformerError("depth event with a non-finite depth")
            state = self._need_state()
            self._move(v, depth_delta(self._handle_cam(v, state), ev.depth, state.R, state.projection))
        elif kind == "move":
            v = self._target_vertex(ev)
            vec = None if ev.vector is None else np.asarray(ev.vector, dtype=np.float64)
            if vec is None or vec.shape != (3,) or not np.all(np.isfinite(vec)):
                raise DeformerError("move event needs a finite model-space vector (3,) in mm")
            self._move(v, vec)
        elif kind == "axes":
            self._axes(ev)
        elif kind == "command":
            self._command(ev)
        elif kind == "pose":
            self._pose_event(ev)
        else:  # buttons: mapped to commands by the input nodes
            self.count(f"ignored_{kind}")

    def remember(self, state: FaceState) -> None:
        """A new fitted state of this face: the latest, and one of the RECENT_STATES by stamp."""
        self.state = state
        self.recent_states[state.stamp] = state
        while len(self.recent_states) > RECENT_STATES:
            self.recent_states.popitem(last=False)

    def _need_state(self, stamp: int = 0) -> FaceState:
        """The state of the frame stamped ``stamp`` when it is among the recent ones, else the latest."""
        st = self.recent_states.get(stamp, self.state) if stamp else self.state
        if st is None:
            raise DeformerError("no face/state yet: cannot turn pixels into the model")
        if st.vertices.shape[0] != self.stack.n:
            raise DeformerError(
                f"face/state has {st.vertices.shape[0]} vertices, face/model {self.stack.n}: waiting for matching ones"
            )
        return st

    def _current_mesh(self, st: FaceState) -> np.ndarray:
        """The deformed fitted mesh (camera space) the user sees: Eq. 5 with the last solve."""
        return merge_deformation(st.vertices.astype(np.float64), st.R, st.scale, self.stack.displacement)

    def _handle_cam(self, v: int, st: FaceState) -> np.ndarray:
        """Camera-space position of handle ``v`` at its current target."""
        offset = self.stack.handle_position(v) - self.stack.rest[v]
        return st.vertices[v].astype(np.float64) + st.scale * (st.R @ offset)

    def _pick(self, ev: InputEvent) -> int:
        if ev.landmark:
            return self.stack.landmark_vertex(ev.landmark)
        if not (np.isfinite(ev.x) and np.isfinite(ev.y)):
            raise DeformerError("press without a landmark name needs finite pixel coordinates x, y")
        st = self._need_state(ev.stamp)
        with self.stage("pick"):
            hit = pick_vertex(ev.x, ev.y, st.K, self._current_mesh(st), self.stack.triangles, st.projection)
        if hit is None:
            self.count("pick_miss")
            self.last_diagnostic = f"pick_miss: pixel ({ev.x:.1f}, {ev.y:.1f}) is not on the face"
            self.report(self.last_diagnostic)
            return -1
        return hit.vertex

    def _press(self, ev: InputEvent):
        v = self._pick(ev)
        if v < 0:
            return
        if self.pointers and self.stack.edits:
            self.stack.add_handle(v)  # another pointer is held: same edit (e.g. a two-handle squeeze)
        else:
            self.stack.begin([v])
        self.pointers[ev.handle] = (v, ev.x, ev.y)
        self.selected = v
        self.dirty = True
        self.count("press")

    def _drag(self, ev: InputEvent):
        if ev.handle not in self.pointers:
            raise DeformerError(f"drag of pointer {ev.handle} without a press")
        if not (np.isfinite(ev.x) and np.isfinite(ev.y)):
            raise DeformerError("drag needs finite pixel coordinates x, y")
        v, x0, y0 = self.pointers[ev.handle]
        st = self._need_state(ev.stamp)
        if not (np.isfinite(x0) and np.isfinite(y0)):  # pressed at a landmark: start from its pixel
            x0, y0 = project(self._handle_cam(v, st)[None], st.K, st.projection)[0]
        self._move(v, drag_delta(self._handle_cam(v, st), (x0, y0), (ev.x, ev.y), st.K, st.R, st.scale, st.projection))
        self.pointers[ev.handle] = (v, ev.x, ev.y)
        self.count("drag")

    def _target_vertex(self, ev: InputEvent) -> int:
        if ev.handle in self.pointers:
            return self.pointers[ev.handle][0]
        if ev.landmark:
            v = self.stack.landmark_vertex(ev.landmark)
            if self.stack.edit_of(v) is None:
                self.stack.begin([v])
            return v
        if self.selected is None:
            raise DeformerError(f"{ev.kind} event with no handle selected: press first")
        return self.selected

    def _move(self, v: int, delta: np.ndarray):
        k = self.stack.edit_of(v)
        if k is None:
            raise DeformerError(f"vertex {v} is no longer a handle (undone or reset)")
        self.stack.move_handle(v, delta, edit=k)
        self.dirty = True

    def _axes(self, ev: InputEvent):
        self._integrate_axes()
        axes = np.zeros(0) if ev.axes is None else ev.axes
        self.velocity = axes_velocity(axes, self.params.joystick_speed, self.params.joystick_deadzone)
        self.last_axes_at = time.monotonic()

    def _integrate_axes(self):
        now = time.monotonic()
        dt, self.last_axes_at = now - self.last_axes_at, now
        if not np.any(self.velocity) or self.selected is None or self.stack.edit_of(self.selected) is None:
            return
        self._move(self.selected, self.velocity * min(dt, 0.1))

    def _set_pose(self, pose: PoseOffset | None) -> None:
        """Make ``pose`` the face's pose offset (None: leave it), flagging a change."""
        if pose is not None and pose != self.pose:
            self.pose, self.pose_changed = pose, True

    def _pose_event(self, ev: InputEvent) -> None:
        """A "pose" event: its change (``pose`` (6,) finite, else ``argument`` text such as
        "yaw=2") added to the pose offset, each component (and the sum) clamped to its limit."""
        try:
            if ev.pose is not None:
                change = PoseOffset.clamped(ev.pose)
            elif ev.argument:
                change = parse_pose_offset(ev.argument)
            else:
                raise ValueError("a pose event needs pose (6,) [yaw, pitch, roll deg, x, y, z mm] "
                                 "or an argument such as 'yaw=2,pitch=-1'")
        except ValueError as exc:
            raise DeformerError(str(exc)) from None
        self._set_pose(self.pose + change)
        self.count("pose")

    def _save_preset(self, path: Path) -> Path:
        """Write the edits, pins and (when not zero) the pose offset as a preset at ``path``;
        the absolute path written (OSError when it cannot be written)."""
        doc = self.stack.to_preset()
        if not self.pose.is_zero:
            doc["pose"] = pose_to_preset(self.pose)
        path = Path(path).expanduser().resolve()
        path.write_text(json.dumps(doc, indent=1))
        return path

    def _preset_path(self, argument: str) -> Path:
        if not argument:
            raise DeformerError("preset command needs a path argument")
        p = Path(argument).expanduser()
        return p if p.is_absolute() or not self.params.preset_dir else Path(self.params.preset_dir).expanduser() / p

    def _command(self, ev: InputEvent):
        cmd = ev.command
        if cmd == "reset":
            self.stack.clear()
            self.pointers.clear()
            self.selected = None
            self.velocity[:] = 0
            self._set_pose(PoseOffset())
        elif cmd == "reset_pose":  # rigid: published without a solve
            self._set_pose(PoseOffset())
            return
        elif cmd == "undo":
            if not self.stack.undo():
                self.count("undo_empty")
            self.pointers.clear()
            self.selected = None
        elif cmd == "save_preset":
            path = self._preset_path(ev.argument)
            try:
                path = self._save_preset(path)
            except OSError as exc:
                raise DeformerError(f"cannot write preset {path}: {exc}") from exc
            self.last_saved_preset = str(path)
            self.report_saved(self.last_saved_preset)
            self.log.info("saved the edits as preset %s", path)
            self.count("preset_saved")
            return
        elif cmd == "load_preset":
            if not ev.argument:
                raise DeformerError("preset command needs a path argument")
            # a file (relative to preset_dir) or the name of a shipped preset, e.g. "nose_longer"
            doc = scale_preset(read_preset_file(find_preset(ev.argument, self.params.preset_dir)), self.params.strength)
            self.stack.apply_preset(doc)
            self._set_pose(preset_pose(doc))
            self.loaded = (doc, _fingerprint(self.stack))
            self.pointers.clear()
            self.selected = None
            self.count("preset_loaded")
        elif cmd == "select_edit":
            # Later depth / move / axes events without a pointer act on this edit's first handle.
            try:
                k = int(ev.argument)
                edit = self.stack.edits[k]
            except (ValueError, IndexError):
                raise DeformerError(f"select_edit needs an edit number in 0..{len(self.stack.edits) - 1} "
                                    f"(or negative from the end), got {ev.argument!r}") from None
            self.selected = min(edit.offsets)
            self.count("edit_selected")
            return
        elif cmd == "toggle_static":
            v = self._pick(ev)
            if v < 0:
                return
            self.stack.toggle_static(v)
        else:
            self.count("ignored_command")
            return
        self.dirty = True



def _fingerprint(stack: EditStack) -> str:
    """The edits and pins of a stack as text, to tell whether they changed since a preset was loaded."""
    doc = stack.to_preset()
    return json.dumps([doc["edits"], doc["static"]])
