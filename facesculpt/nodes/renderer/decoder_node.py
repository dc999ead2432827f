"""The decoder node: ``facesculpt run decoder`` (facesculpt/launch/coding.yaml): a coded talking head rendered.

Subscribes the latched ``coding/key`` (CodedKey: the keyframe) and ``coding/basis`` (CodedBasis:
the expression basis) and ``coding/frame`` (CodedFrame) of an encoder node (``facesculpt run
encoder``, the talking-heads room), on this machine or another (``transport: tcp``),
and renders each frame from the keyframe (:class:`.coded_face.CodedFace`) into a window, a video
file and/or ``render/image``. Frames of another key or basis than the ones at hand are skipped and
counted until those arrive; a key or basis that cannot be decoded is dropped with its reason
logged.
"""

from __future__ import annotations

import json

import numpy as np

from facesculpt.coding.fsc import FORMAT_VERSION, unpack_basis, unpack_key_arrays, unpack_records
from facesculpt.msgs import CodedBasis, CodedFrame, CodedKey, Image
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import Param
from facesculpt.runtime.qos import LATCHED

from .coded_face import CodedFace, coded_compositor
from .compositor import Compositor


class DecoderNode(Node):
    """Renders coding/frame with coding/key (see the module docstring)."""

    NAME = "decoder"
    TOPICS = ("render/image", "coding/key", "coding/basis", "coding/frame")
    PARAMS = {
        "window": Param(False, "show the decoded frames in a window (Q or Escape stops the graph)"),
        "output": Param("", "video file to write (\"\": none)"),
        "fps": Param(0.0, "frame rate of the video file, frames/s (0: the key's)", range=(0.0, 1000.0)),
        "publish": Param(True, "publish render/image"),
        "title": Param("facesculpt decoder", "window title"),
        "head_motion": Param(True, "carry the face's motion over the hair and neck around it (off: only the face "
                                   "moves, over the keyframe's still head; cheaper for a face that fills the frame)"),
        "body_motion": Param(True, "with head_motion, carry the head's sway over the neck and body below the jaw "
                                   "(off: the keyframe's body stays still)"),
    }

    def setup(self):
        self.face: CodedFace | None = None
        self.key: tuple | None = None  # (version, header, JPEG bytes, key arrays, triangles)
        self.steps: np.ndarray | None = None
        self.versions = (-1, -1)       # (key, basis) of self.face
        self.window = None
        self.video = None
        self.fps = 30.0
        self.K = np.eye(3)
        self.image_pub = self.advertise("render/image", Image) if self.params.publish else None
        self.subscribe("coding/key", CodedKey, self.on_key, qos=LATCHED)
        self.subscribe("coding/basis", CodedBasis, self.on_basis, qos=LATCHED)
        self.subscribe("coding/frame", CodedFrame, self.on_frame)
        if self.params.window:
            self.timer(1.0 / 60.0, self.on_tick)

    def _refuse(self, what: str, exc: Exception) -> None:
        self.count(f"bad_{what.split('/')[1]}")
        self.last_error = f"{what}: {exc}"
        self.log.warning("%s", self.last_error)

    def on_key(self, msg: CodedKey) -> None:
        try:
            header = json.loads(msg.header)
            if header.get("version") != FORMAT_VERSION:
                raise ValueError(f"it is coded in format version {header.get('version')}; this decoder reads "
                                 f"{FORMAT_VERSION} (update the encoder's side)")
            arrays = unpack_key_arrays(msg.arrays.tobytes(), int(header["vertices"]), header.get("K"))
            if int(header["width"]) < 1 or int(header["height"]) < 1:
                raise ValueError("its frame size is not positive")
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            self._refuse("coding/key", exc)
            return
        self.key = (msg.version, header, msg.keyframe.tobytes(), arrays, np.array(msg.triangles))
        self.fps = float(self.params.fps or header.get("fps") or 30.0)
        if header.get("K") is not None:
            self.K = np.asarray(header["K"], np.float64)
        self.log.info("coding: key %d (%dx%d)", msg.version, header["width"], header["height"])
        self.count("keys")

    def on_basis(self, msg: CodedBasis) -> None:
        if self.key is None or msg.key_version != self.key[0]:
            self.count("basis_without_its_key")
            return
        version, header, jpeg, key_arrays, triangles = self.key
        try:
            arrays = dict(key_arrays, **unpack_basis(msg.arrays.tobytes(), int(header["vertices"]), msg.basis_steps,
                                                     triangles))
            _, pose, coeffs = unpack_records(msg.record.tobytes(), msg.coeff_steps)
            if len(msg.coeff_steps) != len(msg.basis_steps) or len(pose) != 1:
                raise ValueError("its steps and its keyframe record do not match its basis")
            compositor = self._compositor(int(header["width"]), int(header["height"]))
            self.face = CodedFace(header, jpeg, arrays, triangles, pose[0], coeffs[0], compositor=compositor,
                                  head_motion=self.params.head_motion, body_motion=self.params.body_motion)
        except RuntimeError as exc:  # no window could be opened: the node cannot do what it was asked
            self.log.error("%s", exc)
            self.shutdown()
            return
        except (ValueError, KeyError, IndexError) as exc:
            self._refuse("coding/basis", exc)
            return
        self.steps, self.versions = np.asarray(msg.coeff_steps), (version, msg.version)
        self.log.info("coding: basis %d of key %d (%d coefficients a frame)", msg.version, version, len(self.steps))
        self.count("bases")

    def _compositor(self, width: int, height: int) -> Compositor:
        """The compositor for a key of this size, on the window's GL context when there is one."""
        if self.face is not None and (self.face.width, self.face.height) == (width, height):
            return self.face.compositor
        if self.face is not None:  # a key of another size: the old face can no longer be drawn
            self.face.compositor.release()
            self.face, self.versions = None, (-1, -1)
        if self.window is not None:
            self.window.close()
            self.window = None
        ctx = None
        if self.params.window:
            from .window import Window

            self.window = Window(width, height, self.params.title)
            ctx = self.window.ctx
        return coded_compositor(width, height, ctx=ctx)

    def on_frame(self, msg: CodedFrame) -> None:
        if self.face is None or (msg.key_version, msg.basis_version) != self.versions:
            self.count("frames_without_their_basis")
            return
        try:
            present, pose, coeffs = unpack_records(msg.record.tobytes(), self.steps)
            if len(present) != 1:
                raise ValueError(f"{len(present)} records in one frame")
        except ValueError as exc:
            self._refuse("coding/frame", exc)
            return
        with self.stage("render"):
            out = self.face.render(bool(present[0]), pose[0], coeffs[0])
        with self.stage("output"):
            if self.image_pub is not None:
                self.image_pub.publish(Image(stamp=msg.stamp, seq=msg.seq, frame_id=msg.frame_id, image=out, K=self.K))
            if self.params.output:
                if self.video is None:
                    from .video_out import VideoOutput

                    self.video = VideoOutput(self.params.output, self.fps)
                self.video.write(out)
            if self.window is not None:
                self.window.show(out)
        self.count("rendered")

    def on_tick(self) -> None:
        if self.window is not None:
            self.window.poll()
            if self.window.closed:
                self.log.info("window closed: stopping the graph")
                self.stop_graph()

    def teardown(self) -> None:
        if self.video is not None:
            self.video.close()
        if self.face is not None:
            self.face.compositor.release()
        if self.window is not None:
            self.window.close()
