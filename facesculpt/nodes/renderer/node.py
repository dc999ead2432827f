"""The renderer node: pairs frames with face states, merges the edit, composites, shows.

Subscribes: camera/image (Image), face/state (FaceState), face/model (FaceModel,
latched: the triangles), face/deformation (Deformation), hands/landmarks (HandLandmarks, when a
hands node runs: the hands' region is composited back from the input, so nothing re-rendered
covers a hand in front of the face). Publishes: render/image
(Image, when ``publish``), input/events (InputEvent, from the window; in its landmark correction mode, L,
left-drags become ``correct_landmark`` commands for the fitter: ``correction_mode.py``), diagnostics
(stage times: pair, merge, camera, texture, draw, readback, inpaint, composite,
output). Writes ``output`` (a video file) when set.

Params: window (open a glfw window), pairing ("latest" | "sync"), buffer (frames kept
for sync), sync_timeout_s, max_state_age_s, inpaint ("pushpull" | "telea" | "ns" | "patch" | "drag"), plate
("on" | "off": the background plate, ``background_plate.py``), plate_max_age,
feather_px, dilate_px, outline_band, subdivision, output (video path), fps (of the video file), publish, overlay
(fps, stage times, handles, ROI, pins and key help in the window), title, close (what closing
the window stops: "graph" | "node"), hands (keep the hands in front), hands_max_age_s,
pinch_markers (a marker at each pinch of the pinch node's input/events, ``pinch_markers.py``),
atlas ("on" | "off": the face's texture memory, ``texture_atlas.py``), atlas_size, atlas_every,
texture_size and texture_period_s (face/texture: FaceTexture, latched, the atlas downscaled, with
atlas on; the UV layout is a frontal projection of the first face/model's neutral per face),
face_camera and face_camera_limit (pose edits, ``pose_edit.py``: each face is turned by its
Deformation ``pose`` plus, with face_camera above 0, a turn toward the camera; the head
around the face moves with it).
"""

from __future__ import annotations

import dataclasses
import os
import time

import numpy as np

from facesculpt.geometry import merge_deformation
from facesculpt.geometry.hand_regions import hand_region_mask
from facesculpt.geometry.pose_offset import FACE_CAMERA_SMOOTHING_MAX_S, PoseOffset
from facesculpt.msgs import Deformation, FaceModel, FaceState, FaceTexture, FrameDone, HandLandmarks, Image, InputEvent
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import ConfigurationError, Param, option_params
from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE, LATCHED, SENSOR_DATA

from .compositor import Compositor
from .compositor_options import OUTLINE_BAND, CompositorOptions
from .correction_mode import CorrectionMode
from .face_groups import FaceGroups
from .frame_size_defaults import (
    AUTO_MAX_FINE_EDGE_PX,
    MAX_OUTLINE_BAND,
    auto_interpolation,
    auto_outline_band,
    auto_subdivision,
)
from .mouth_interior import paint_opened_mouth
from .pairing import FramePairer
from .person_segmentation import MissingNetworkError, PersonSegmenter
from .pinch_markers import PinchMarkers, draw_pinch_markers
from .pose_edit import (
    FACE_CAMERA_LIMIT_DEG,
    FACE_CAMERA_LIMIT_RANGE,
    FACE_CAMERA_SMOOTHING_S,
    PoseEdits,
)
from .pose_limit import PoseLimiter, turn_within_limits
from .subdivision import MAX_FINE_EDGE_PX
from .texture_atlas import uv_layout

#: The compositor's options in live use: the atlas learned every other frame, on a thread of its own
#: (the frames between only read it), so that learning it costs the frame rate little.
LIVE = CompositorOptions(atlas_every=2, atlas_thread=True)


class RendererNode(Node):
    """Renders the deformed face into the video: window, video file and/or render/image."""

    NAME = "renderer"
    TOPICS = ("render/image", "input/events", "render/done", "face/texture", "camera/image", "face/state",
              "face/model", "face/deformation", "hands/landmarks")
    PARAMS = {
        # the compositor's own options, declared once in CompositorOptions (LIVE: the live defaults)
        **option_params(LIVE, ("inpaint", "feather_px", "dilate_px", "plate_max_age", "atlas_size", "atlas_every")),
        "window": Param(False, "open a window (shows the result, mouse drags become input/events)"),
        "pairing": Param("latest", "frames with face states: latest (the newest state) or sync (each frame's own)",
                         choices=("latest", "sync")),
        "buffer": Param(30, "frames kept while waiting for their state (sync)", range=(1, 1000)),
        "backlog": Param("auto", "frames ready at once when the renderer fell behind (sync): newest (render the "
                                 "newest, skip the others: latency stays low), all (render every one: nothing is "
                                 "lost, latency grows), auto (all when writing a video file, else newest)",
                         choices=("auto", "newest", "all")),
        "sync_timeout_s": Param(0.5, "sync: a frame this much older than the newest is shown without a face, s",
                                range=(0.0, 60.0)),
        "max_state_age_s": Param(0.5, "latest: the oldest state (relative to the frame) still drawn, s",
                                 range=(0.0, 60.0)),
        "mouth": Param("off", "paint: where an edit opens a mouth that is closed in the frame, paint a dark "
                              "interior with a soft teeth band instead of stretching the lips (face-mesh "
                              "model; on in facesculpt/launch/reenact.yaml); off: the lips stretch", choices=("off", "paint")),
        "interpolation": Param("auto", "kernel the frame is resampled with where the face moved: sinc (a long "
                                       "windowed sinc: keeps the skin's finest detail), cubic (faster, softer), "
                                       "lanczos (Lanczos-4), or auto: sinc for frames smaller than 1280x720, "
                                       "cubic from there on, where the renderer limits the frame rate",
                               choices=("auto", "sinc", "cubic", "lanczos")),
        "plate": Param("off", "background plate: the background seen behind the face in earlier frames (registered "
                              "when the camera moves; never the person: `facesculpt setup`'s person segmentation) "
                              "replaces the fill where known", choices=("on", "off")),
        "outline_band": Param("auto", f"how far past the fitted outline a shape edit's motion is carried, fading "
                                      f"out, as a share of the face's size (a real outline the fit lies inside moves "
                                      f"with the face), in [0, {MAX_OUTLINE_BAND}]; 0: not at all; auto: {OUTLINE_BAND} "
                                      f"as process does for frames smaller than 1280x720, 0 from there on, where the "
                                      f"renderer limits the frame rate"),
        "subdivision": Param("auto", f"Loop subdivision levels of the render mesh, 0 to 3 (smooth edited outlines); "
                                     f"auto: as few as make its edges {MAX_FINE_EDGE_PX:g} px long on screen "
                                     f"(at least one, within 16384 triangles) for frames smaller than 1280x720, "
                                     f"{AUTO_MAX_FINE_EDGE_PX:g} px from there on"),
        "output": Param("", "video file to write (\"\": none)"),
        "fps": Param(30.0, "frame rate of the video file, frames/s", range=(1.0, 1000.0)),
        "publish": Param(True, "publish render/image"),
        "overlay": Param(True, "draw fps, stage times, handles, ROI, pins and the key help in the window"),
        "title": Param("facesculpt", "window title"),
        "close": Param("graph", "what Q, Escape or the window's close button stop: graph (every node; "
                                "launch exits 0) or node (this renderer only; the launcher does not respawn it)",
                       choices=("graph", "node")),
        "hands": Param(True, "keep the hands of hands/landmarks (a hands node) in front of the face: their region "
                             "is composited back from the input"),
        "hands_max_age_s": Param(0.25, "the oldest hands message (relative to the frame) still used when the "
                                       "frame's own has not arrived, s", range=(0.0, 10.0)),
        "pinch_markers": Param(False, "draw a small marker at each pinch (the pinch node's press..release on "
                                      "input/events) on the output frame: window, video and render/image"),
        "atlas": Param("off", "texture memory of the face (UV atlas): learned over the frames; where the frame sees "
                              "the edited surface badly (stretched, hidden) its colours come from it; published on "
                              "face/texture", choices=("on", "off")),
        "texture_size": Param(128, "face/texture: the atlas downscaled to this many texels a side", range=(16, 2048)),
        "texture_period_s": Param(1.0, "face/texture: published at most this often, s", range=(0.0, 3600.0)),
        "face_camera": Param(0.0, "turn each face this share of the way toward looking into the camera (0: off, "
                                  "1: all the way, up to face_camera_limit), on top of the deformer's pose edit; the "
                                  "head around the face moves with it", range=(0.0, 1.0)),
        "face_camera_smoothing_s": Param(FACE_CAMERA_SMOOTHING_S, "face_camera: time constant smoothing the direction "
                                         "to the camera over the frames, s (0: none)",
                                         range=(0.0, FACE_CAMERA_SMOOTHING_MAX_S)),
        "face_camera_limit": Param(FACE_CAMERA_LIMIT_DEG, "face_camera: the largest turn, degrees of yaw and of "
                                                          "pitch", range=FACE_CAMERA_LIMIT_RANGE),
        "pose_limit": Param(True, "draw only the share of a pose edit that what the video showed of the surface it "
                                  "reveals allows, reduced smoothly beyond it (a note in the window says how far)"),
        "keyframes": Param("off", "keep views of each face at the poses it shows and render a turned head's surface "
                                  "from the closest one where it sees it better than the frame (image-based rendering "
                                  "for pose edits; a few ms a frame)", choices=("on", "off")),
    }
    NOTICE_S = 3.0                    # how long the window shows a notice (a saved preset), s
    _notice: tuple[str, float] | None = None   # (text, monotonic time it ends)
    _saving = ""                      # the preset the window asked for, until the deformer reports it
    _diagnostics_sub = None           # diagnostics, subscribed to at the first save

    def setup(self):
        p = self.params
        if p.window and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise ConfigurationError("renderer: window=true needs a display (DISPLAY is not set); "
                                     "use output=FILE.mp4 or publish=true to run headless")
        try:
            auto_outline_band(p.outline_band, 1, 1)
            auto_subdivision(p.subdivision, 1, 1)
            # the plate learns nothing where a person is (their hair, neck, shoulders)
            self.segmenter = PersonSegmenter() if p.plate == "on" else None
        except (ValueError, MissingNetworkError) as exc:
            raise ConfigurationError(f"renderer: {exc}") from None
        qos = EVERY_MESSAGE if p.pairing == "sync" else SENSOR_DATA  # sync must see every frame and state to pair them
        self.pairer = FramePairer(p.pairing, capacity=p.buffer, timeout_ns=int(p.sync_timeout_s * 1e9),
                                  max_age_ns=int(p.max_state_age_s * 1e9))
        self.groups = FaceGroups(capacity=p.buffer)  # the states of one frame (one per face)
        self.every_frame = p.backlog == "all" or (p.backlog == "auto" and bool(p.output))
        self._ready: list = []            # pairs ready to render, rendered after the batch of messages
        self.image_pub = self.advertise("render/image", Image) if p.publish else None
        self.events_pub = self.advertise("input/events", InputEvent) if p.window else None
        # One FrameDone per handled frame: an offline camera (camera.wait_for) sends the next one on it.
        self.done_pub = self.advertise("render/done", FrameDone, qos=EVERY_MESSAGE)
        self.texture_pub = self.advertise("face/texture", FaceTexture, qos=LATCHED) if p.atlas == "on" else None
        self._uv: dict = {}               # face id -> (model id, (V, 2) UV layout) for the atlas
        self._texture_sent = -1e18
        self.subscribe("camera/image", Image, self.on_image, qos=qos)
        self.subscribe("face/state", FaceState, self.on_state, qos=qos)
        self.subscribe("face/model", FaceModel, self.on_model)
        self.subscribe("face/deformation", Deformation, self.on_deformation)
        self._hands: list[HandLandmarks] = []  # the newest hands messages, oldest first
        if p.hands:
            self.subscribe("hands/landmarks", HandLandmarks, self.on_hands, qos=EVERY_MESSAGE)
        self.pinches = PinchMarkers() if p.pinch_markers else None
        if self.pinches is not None:
            self.subscribe("input/events", InputEvent, self.pinches.push, qos=EVENTS)
        self.model: FaceModel | None = None
        self.deformation: Deformation | None = None
        self.compositor: Compositor | None = None
        self.window = None
        self.video = None
        self._shown_at: list[float] = []
        self._overlay_px: np.ndarray | None = None  # (V, 2) the edited face's deformed pixels this frame
        self.correction = CorrectionMode()  # the window's landmark correction mode (L)
        self.poses = PoseEdits(p.face_camera, p.face_camera_limit, p.face_camera_smoothing_s)
        self.pose_limiter = PoseLimiter() if p.pose_limit else None
        self._turn_share = 1.0   # the share of the last pose edit drawn
        if p.window:
            self.timer(1.0 / 120.0, self.on_tick)

    # -- inputs ----------------------------------------------------------------------------------
    def on_model(self, msg: FaceModel) -> None:
        self.model = msg

    def on_deformation(self, msg: Deformation) -> None:
        self.deformation = msg

    def on_hands(self, msg: HandLandmarks) -> None:
        self._hands = (self._hands + [msg])[-self.params.buffer:]

    def _keep_mask(self, stamp: int, w: int, h: int) -> np.ndarray | None:
        """(h, w) bool the hands' region of the frame stamped ``stamp``: from its own hands
        message, else the newest one at most ``hands_max_age_s`` from it; None without hands."""
        if not self._hands:
            return None
        own = [m for m in self._hands if m.stamp == stamp]
        msg = own[-1] if own else self._hands[-1]
        if not own and abs(stamp - msg.stamp) > self.params.hands_max_age_s * 1e9:
            return None
        if msg.points.shape[0] == 0 or list(msg.image_size) not in ([w, h], [0, 0]):
            return None
        self.count("hands_kept")
        return hand_region_mask(msg.points, w, h)

    def on_image(self, msg: Image) -> None:
        if self.compositor is not None:  # what needs only the frame starts while its face is fitted
            self.compositor.prefetch(msg.image)
        with self.stage("pair"):
            pairs = self.pairer.push_frame(msg.stamp, msg)
        self._render_all(pairs)

    def on_state(self, msg: FaceState) -> None:
        has_face = msg.vertices.shape[0] > 0
        if not has_face:
            self.count("state_without_face")
        pairs = []
        with self.stage("pair"):
            for stamp, states in self.groups.push(msg.stamp, msg, msg.faces if has_face else 0, msg.face_id):
                pairs += self.pairer.push_state(stamp, states or None)
        for name, n in self.groups.counters.items():
            self.counters[f"pairing_{name}"] = n
        self._render_all(pairs)

    # -- the frame -------------------------------------------------------------------------------
    def _render_all(self, pairs) -> None:
        for name, n in self.pairer.counters.items():
            self.counters[f"pairing_{name}"] = n
        self._ready += pairs

    def after_messages(self) -> None:
        """Render the pairs the batch of messages made ready: all of them, or (``backlog``) only the
        newest, the older ones acknowledged as not rendered (an offline camera sends on) and counted."""
        pairs, self._ready = self._ready, []
        if not self.every_frame and len(pairs) > 1:
            for pair in pairs[:-1]:
                self.done_pub.publish(FrameDone(stamp=pair.frame.stamp, seq=pair.frame.seq,
                                                frame_id=pair.frame.frame_id, rendered=False))
            self.count("skipped_behind", len(pairs) - 1)
            pairs = pairs[-1:]
        for pair in pairs:
            self._render(pair.frame, pair.state)

    def _deformed_vertices(self, state: FaceState) -> np.ndarray:
        """Eq. 5 through the deformer's merge, with the edit of this state's face; the fitted
        vertices when there is no usable edit."""
        d = self.deformation
        if d is None or d.displacement.shape[0] == 0:
            return state.vertices
        displacement = d.displacement_of(state.face_id)
        if d.model_id != state.model_id or displacement.shape != state.vertices.shape:
            self.count("deformation_model_mismatch")
            return state.vertices
        with self.stage("merge"):
            return merge_deformation(state.vertices, state.R, state.scale, displacement)

    def _pose_of(self, state: FaceState):
        """The deformer's pose offset of ``state``'s face (a PoseOffset; zero without one)."""
        d = self.deformation
        values = np.zeros(6) if d is None or d.model_id != state.model_id else d.pose_of(state.face_id)
        return PoseOffset.clamped(values)

    def _render_face(self, out: np.ndarray, state: FaceState, keep, stamp: int) -> np.ndarray:
        """``out`` with ``state``'s face composited: its edit merged (Eq. 5), then its pose edit
        (the deformer's pose plus face_camera's turn, ``pose_edit.py``) with the head's motion
        carried over the head around it. ValueError on input the compositor refuses."""
        deformed = self._deformed_vertices(state)
        edit = self.poses.edit(state, self._pose_of(state), self.model.neutral_of(state.face_id), stamp)
        self._turn_share = 1.0 if edit is None else self._turn_share
        if edit is not None:
            with self.stage("pose"):
                if self.pose_limiter is None:
                    deformed = self.poses.apply(deformed, state, edit)
                else:
                    deformed, self._turn_share = turn_within_limits(
                        self.pose_limiter, state.face_id, stamp * 1e-9, state, deformed, edit, self.model.triangles,
                        self.compositor.views)
            self.count("pose_edited")
        return self.compositor.render(out, state.vertices, state.projected, self.model.triangles, deformed,
                                      keep_mask=keep, uv=self._uv_of(state), face_key=state.face_id,
                                      head_motion=edit is not None)

    def _ensure_output(self, width: int, height: int) -> bool:
        """(Re)create window and compositor for this frame size; False when the size is unusable."""
        if self.compositor is not None and (self.compositor.width, self.compositor.height) == (width, height):
            return True
        if self.compositor is not None:
            self.log.warning("frame size changed to %dx%d: recreating the renderer", width, height)
            self.compositor.release()
            self.compositor = None
            if self.window is not None:
                self.window.close()
                self.window = None
        ctx = None
        if self.params.window:
            from .window import Window

            try:
                self.window = Window(width, height, self.params.title)
            except RuntimeError as exc:
                self.log.error("%s", exc)
                self.shutdown()
                return False
            ctx = self.window.ctx
        p = self.params
        subdivision, max_fine_edge_px = auto_subdivision(p.subdivision, width, height)
        options = dataclasses.replace(
            LIVE, inpaint=p.inpaint, feather_px=p.feather_px, dilate_px=p.dilate_px, plate_max_age=p.plate_max_age,
            atlas_size=p.atlas_size, atlas_every=p.atlas_every, atlas=p.atlas == "on", plate=p.plate == "on",
            keyframes=p.keyframes == "on", outline_band=auto_outline_band(p.outline_band, width, height),
            interpolation=auto_interpolation(p.interpolation, width, height), subdivision=subdivision,
            max_fine_edge_px=max_fine_edge_px)
        self.compositor = Compositor(width, height, options, ctx=ctx, segmenter=self.segmenter)
        return True

    def _render(self, frame_msg: Image, states: list[FaceState] | None) -> None:
        """Composite every face of ``states`` (None or []: no face) into the frame, each with its
        own edit, and hand the result to the window, the video file and render/image."""
        frame = frame_msg.image
        h, w = frame.shape[:2]
        if not self._ensure_output(w, h):
            return
        out = frame
        drawn = False
        handles_px = roi_px = None
        self._overlay_px = None
        if not states:
            self.count("no_face")
        keep = self._keep_mask(frame_msg.stamp, w, h) if states else None
        for state in states or []:
            if self.model is None or self.model.model_id != state.model_id:
                self.count("no_model")
                continue
            if state.image_size and list(state.image_size) not in ([w, h], [0, 0]):
                self.count("state_size_mismatch")
                continue
            try:
                out = self._render_face(out, state, keep, frame_msg.stamp)
            except ValueError as exc:
                self.count("bad_input")
                self.log.warning("frame %d, face %d not rendered: %s", frame_msg.stamp, state.face_id, exc)
                continue
            if self.params.mouth == "paint" and self.compositor.deformed_px is not None:
                out = paint_opened_mouth(out, state.projected, self.compositor.deformed_px, keep)
            drawn = True
            for name, ms in self.compositor.timings.items():
                if name != "total":
                    self.stage_times.setdefault(name, []).append(ms)
            d, px = self.deformation, self.compositor.deformed_px
            if d is not None and px is not None and (d.face_id == state.face_id or len(states) == 1):
                # the window marks the face being edited, on the surface drawn (no window: no marks)
                if self.window is not None:
                    px = self.compositor.drawn_px(px)
                self._overlay_px = px
                handles_px = px[d.handles[d.handles < len(px)]]
                roi_px = px[d.roi[d.roi < len(px)]]
        self.correction.observe(states)
        self._publish_texture(frame_msg, states)
        if self.pinches is not None:
            out = draw_pinch_markers(out, self.pinches.at(frame_msg.stamp))
        with self.stage("output"):
            if self.image_pub is not None:
                self.image_pub.publish(Image(stamp=frame_msg.stamp, seq=frame_msg.seq, frame_id=frame_msg.frame_id,
                                             image=out, K=frame_msg.K))
            if self.params.output:
                if self.video is None:
                    from .video_out import VideoOutput

                    self.video = VideoOutput(self.params.output, self.params.fps)
                self.video.write(out)
            if self.window is not None:
                self._show(out, handles_px, roi_px)
        self.count("rendered")
        self.done_pub.publish(FrameDone(stamp=frame_msg.stamp, seq=frame_msg.seq, frame_id=frame_msg.frame_id,
                                        rendered=drawn))

    def _uv_of(self, state: FaceState) -> np.ndarray | None:
        """The UV layout of ``state``'s face for the atlas (None with the atlas off): a frontal
        projection of its neutral in the first face/model seen for it (fixed until the model
        changes, so the atlas keeps its layout while the neutral is learned)."""
        if self.texture_pub is None:
            return None
        got = self._uv.get(state.face_id)
        if got is None or got[0] != self.model.model_id or len(got[1]) != len(state.vertices):
            got = (self.model.model_id, uv_layout(self.model.neutral_of(state.face_id)))
            self._uv[state.face_id] = got
        return got[1]

    def _publish_texture(self, frame_msg: Image, states) -> None:
        """face/texture (latched): the first rendered face's atlas, downscaled, at most every
        ``texture_period_s``."""
        if self.texture_pub is None or not states or self.compositor is None:
            return
        now = time.monotonic()
        atlas = self.compositor.atlases.get(states[0].face_id)
        uv = self._uv.get(states[0].face_id)
        if atlas is None or uv is None or atlas.updates == 0 or now - self._texture_sent < self.params.texture_period_s:
            return
        import cv2

        n = self.params.texture_size
        image = cv2.resize(atlas.image(), (n, n), interpolation=cv2.INTER_AREA)
        conf = cv2.resize(np.rint(atlas.confidence() * 255).astype(np.uint8), (n, n), interpolation=cv2.INTER_AREA)
        self.texture_pub.publish(FaceTexture(stamp=frame_msg.stamp, seq=frame_msg.seq, frame_id=frame_msg.frame_id,
                                             model_id=self.model.model_id, face_id=int(states[0].face_id), image=image,
                                             confidence=conf, texcoords=uv[1],
                                             updates=atlas.updates))
        self._texture_sent = now

    def _show(self, out: np.ndarray, handles_px, roi_px) -> None:
        from .overlay import draw_overlay
        from .window import keys_help

        now = time.monotonic()
        self._shown_at = [t for t in self._shown_at if now - t < 1.0] + [now]
        lines = []
        if self.params.overlay:
            t = self.compositor.timings
            lines = [f"{len(self._shown_at)} fps  render {t.get('total', 0.0):.1f} ms",
                     "  ".join(f"{k} {v:.1f}" for k, v in t.items() if k != "total")]
        correcting = self.window.correcting
        if correcting:  # the 68 landmarks to drag, the one under the cursor named
            out = self.correction.draw(out, self.window.pointer)
            lines.append("correction mode: drag a landmark where it belongs (L: back to editing)")
        if self._turn_share < 0.995:
            lines.append(f"turn reduced to {100 * self._turn_share:.0f} %: the video has not shown the surface it reveals")
        if self._notice is not None:
            if now < self._notice[1]:
                lines.append(self._notice[0])
            else:
                self._notice = None
        if self.params.overlay:
            out = draw_overlay(out, lines, handles_px, roi_px, self._pins_px(handles_px),
                               help_lines=[keys_help(self.params.close, correcting)])
        elif lines:
            out = draw_overlay(out, lines)
        self.window.show(out)

    def _pins_px(self, handles_px) -> np.ndarray | None:
        """(S, 2) pixels of the pinned vertices (the deformation's ``static``) on the deformed
        face this frame drew; None when it drew none (``handles_px`` None: no face, no edit)."""
        d, px = self.deformation, self._overlay_px
        if handles_px is None or d is None or px is None:
            return None
        return px[d.static[(d.static >= 0) & (d.static < len(px))]]

    def _notify(self, text: str) -> None:
        """Show ``text`` in the window for NOTICE_S seconds."""
        self._notice = (text, time.monotonic() + self.NOTICE_S)

    def _on_save_sent(self, name: str) -> None:
        """S in the window sent save_preset ``name``: say so, and listen to the deformer's
        diagnostics for where it wrote it (``last_saved_preset``) or why it could not."""
        from facesculpt.msgs import Diagnostics

        self._saving = name
        self._notify(f"saving preset {name}")
        self.log.info("asked the deformer to save the edits as preset %s (relative to its preset_dir)", name)
        if self._diagnostics_sub is None:
            self._diagnostics_sub = self.subscribe("diagnostics", Diagnostics, self._on_diagnostics,
                                                   qos=EVERY_MESSAGE)

    def _on_diagnostics(self, msg) -> None:
        """A node's diagnostics: the preset being saved is confirmed by a ``last_saved_preset``
        with its file name, or reported failed by a ``last_diagnostic`` / ``last_error`` naming it."""
        if not self._saving:
            return
        values = msg.values if isinstance(msg.values, dict) else {}
        saved = values.get("last_saved_preset")
        if isinstance(saved, str) and os.path.basename(saved) == os.path.basename(self._saving):
            self.log.info("%s saved the preset as %s", msg.node, saved)
            self._notify(f"saved preset {saved}")
            self._saving = ""
            return
        for key in ("last_diagnostic", "last_error"):
            problem = values.get(key)
            if isinstance(problem, str) and self._saving in problem:
                self.log.warning("%s did not save the preset: %s", msg.node, problem)
                self._notify(f"preset not saved: {problem}")
                self._saving = ""
                return

    def on_tick(self) -> None:
        if self.window is None:
            return
        for event in self.window.poll():
            if event.pop("correct", False):  # correction mode: a landmark dragged, never an edit
                for command in self.correction.handle(event, time.monotonic()):
                    self.events_pub.publish(InputEvent(stamp=time.time_ns(), source="window", **command))
                    self.count("landmark_corrections_sent")
                continue
            self.events_pub.publish(InputEvent(stamp=time.time_ns(), source="window", **event))
            if event.get("command") == "save_preset":
                self._on_save_sent(event["argument"])
        if self.window.closed:
            if self.params.close == "graph":
                self.log.info("window closed: stopping the graph")
                self.stop_graph()
            else:
                from facesculpt.runtime.parameters import EXIT_NODE_CLOSED

                self.log.info("window closed: stopping the renderer (close=node; the rest of the graph runs on)")
                self.exit_code = EXIT_NODE_CLOSED
                self.shutdown()

    def teardown(self) -> None:
        if self.video is not None:
            self.video.close()
        if self.compositor is not None:
            self.compositor.release()
        if self.window is not None:
            self.window.close()
