"""The message types of the graph (docs/architecture.md "Topics").

Units: pixels for image coordinates, millimetres in model space, nanoseconds
for stamps. Array fields are validated on decode against the dtypes and
shapes declared here; dimension names shared by several fields must agree.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .codec import DecodeError, Message, array, register


@register
@dataclass
class Image(Message):
    """A camera frame or a composited output frame.

    image: (H, W, 3) uint8, BGR.  K: (3, 3) float64 pinhole intrinsics of ``image``, pixels.
    halvings: 0 for a frame as captured; n > 0 for a copy of it halved n times (each pixel the
    mean of a 2 x 2 block, ``facesculpt.geometry.halving``: the camera's ``camera/analysis``),
    whose frame was ``frame_size`` [W, H] px.

    An RGB-D camera's frame also carries its depth image (all three optional, absent on a colour
    camera's frame and in messages recorded before them): depth (DH, DW) uint16 millimetres along
    the depth camera's optical axis, 0 where the camera measured nothing; depth_K (3, 3) float64
    the depth image's own pinhole intrinsics, pixels; depth_to_color (4, 4) float64 the rigid
    transform (mm) from the depth camera's frame to the colour camera's (absent: identity, the
    depth already aligned to the colour camera). See docs/guide/depth-cameras.md.
    """

    TYPE = "Image"
    image: np.ndarray = array("u1", "H", "W", 3)
    K: np.ndarray = array("f8", 3, 3)
    halvings: int = 0
    frame_size: list = field(default_factory=lambda: [0, 0])
    depth: np.ndarray = array("u2", "DH", "DW", optional=True)
    depth_K: np.ndarray = array("f8", 3, 3, optional=True)
    depth_to_color: np.ndarray = array("f8", 4, 4, optional=True)

    def check(self) -> None:
        if self.depth is None:
            if self.depth_K is not None or self.depth_to_color is not None:
                raise DecodeError("Image: depth_K / depth_to_color without a depth image")
            return
        if self.depth_K is None:
            raise DecodeError("Image: a depth image needs its intrinsics depth_K")
        if not np.all(np.isfinite(self.depth_K)) or self.depth_K[0, 0] <= 0 or self.depth_K[1, 1] <= 0:
            raise DecodeError("Image.depth_K: the focal lengths must be finite and positive")
        T = self.depth_to_color
        if T is not None:
            rigid = (np.all(np.isfinite(T)) and np.allclose(T[3], [0, 0, 0, 1])
                     and np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6))
            if not rigid:
                raise DecodeError("Image.depth_to_color must be a rigid transform (rotation, translation mm)")


@register
@dataclass
class FaceLandmarks(Message):
    """Dense landmarks of the faces in one frame (F = 0 when there is no face).

    points: (F, N, 3) float32: x, y in image pixels, z relative depth in the same scale.
    scores: (F,) float32 face presence in 0..1.
    rois:   (F, 5) float32 crop of each face: cx, cy, w, h (pixels), angle (radians).
    track_ids: (F,) int32 the same number for the same tracked face across frames (optional:
    absent means 0, 1, ...).  image_size: [W, H] of the source frame.  K: (3, 3) float64 its intrinsics.
    """

    TYPE = "FaceLandmarks"
    points: np.ndarray = array("f4", "F", "N", 3)
    scores: np.ndarray = array("f4", "F")
    rois: np.ndarray = array("f4", "F", 5)
    track_ids: np.ndarray = array("i4", "F", optional=True)
    image_size: list = field(default_factory=lambda: [0, 0])
    K: np.ndarray = array("f8", 3, 3)


@register
@dataclass
class FaceModel(Message):
    """The neutral mesh of the active model (latched on `face/model`).

    vertices: (V, 3) float32, model space (``units``).  triangles: (T, 3) int32.
    landmark_names[i] is the name of vertex landmark_vertices[i] ((L,) int32).
    ``version`` grows when the model or its learned neutral reference changes.
    Several faces: face_ids (P,) int32 and neutrals (P, V, 3) float32 give each fitted face's own
    neutral (FaceState.face_id); a face not listed (or no lists) uses ``vertices``.
    """

    TYPE = "FaceModel"
    model_id: str = ""
    vertices: np.ndarray = array("f4", "V", 3)
    triangles: np.ndarray = array("i4", "T", 3)
    landmark_names: list = field(default_factory=list)
    landmark_vertices: np.ndarray = array("i4", "L")
    units: str = "mm"
    version: int = 0
    face_ids: np.ndarray = array("i4", "P", optional=True)
    neutrals: np.ndarray = array("f4", "P", "V", 3, optional=True)

    def neutral_of(self, face_id: int) -> np.ndarray:
        """(V, 3) the neutral of face ``face_id``: its own when listed, else ``vertices``."""
        if self.face_ids is not None and self.neutrals is not None:
            hit = np.flatnonzero(self.face_ids == int(face_id))
            if hit.size:
                return self.neutrals[hit[0]]
        return self.vertices


@register
@dataclass
class FaceState(Message):
    """The fitted face of one frame.

    R (3, 3) float64, t (3,) float64, scale: model space -> camera space
    (x_cam = scale * R @ x_model + t).  K (3, 3) float64 intrinsics.
    alpha (S,) / beta (E,) float32 shape and expression coefficients.
    vertices: (V, 3) float32 fitted mesh in camera space; projected: (V, 2) float32 pixels.
    face_id: which face (0 when one face is fitted, else the landmark tracker's track id);
    faces: how many states the fitter publishes for this frame (0: an empty state, V = 0, saying
    the frame has no fitted face, so a renderer pairing frames never waits for one).
    landmarks: (68, 2) float32 pixels, optional: the fit's iBUG-68 points in iBUG order (NaN where
    the fit has none); corrected: the iBUG numbers (1..68) of this face's landmarks a person has
    corrected (command correct_landmark), for the window's correction mode.
    """

    TYPE = "FaceState"
    model_id: str = ""
    R: np.ndarray = array("f8", 3, 3)
    t: np.ndarray = array("f8", 3)
    scale: float = 1.0
    K: np.ndarray = array("f8", 3, 3)
    alpha: np.ndarray = array("f4", "S")
    beta: np.ndarray = array("f4", "E")
    vertices: np.ndarray = array("f4", "V", 3)
    projected: np.ndarray = array("f4", "V", 2)
    residual_px: float = 0.0
    image_size: list = field(default_factory=lambda: [0, 0])
    projection: str = "perspective"
    face_id: int = 0
    faces: int = 1
    landmarks: np.ndarray = array("f4", "L", 2, optional=True)
    corrected: list = field(default_factory=list)


INPUT_KINDS = ("press", "drag", "release", "depth", "move", "axes", "buttons", "command", "pose")
INPUT_COMMANDS = ("reset", "undo", "save_preset", "load_preset", "select_edit", "toggle_static",
                  "correct_landmark", "clear_corrections", "reset_pose")


@register
@dataclass
class InputEvent(Message):
    """One user input (docs/graph/input-events.md has an example of each kind).

    kind: one of INPUT_KINDS.  x, y: frame pixels (press/drag/release/toggle_static).
    landmark: a model landmark name to press at instead of a pixel.
    handle: which pointer/handle (several fingers or devices), default 0.
    depth: mm along the view ray, + toward the camera (kind "depth").
    vector: (3,) float32 model-space displacement in mm (kind "move").
    axes: (A,) float32 joystick axes in -1..1; buttons: bit mask.
    pose: (6,) float32, kind "pose": a change of the face's pose offset (issue 18), added to it:
    yaw, pitch, roll in degrees, x, y, z in mm (camera axes); without it, ``argument`` may give
    the change as text ("yaw=2,pitch=-1", facesculpt.geometry.pose_offset.parse_pose_offset).
    command / argument: kind "command" (INPUT_COMMANDS; argument e.g. a preset path, or for
    correct_landmark the iBUG number 1..68 of the landmark to put at x, y; the fitter handles
    correct_landmark and clear_corrections, the deformer the others; reset_pose clears the pose
    offset alone, reset clears it with every edit).
    face: which face (FaceState.face_id) the event edits; -1: the face under the pointer for
    pixel events, every face for landmark presses and commands, the selected face (else every
    face) for pose events.
    """

    TYPE = "InputEvent"
    kind: str = "press"
    x: float = float("nan")
    y: float = float("nan")
    landmark: str = ""
    handle: int = 0
    depth: float = 0.0
    vector: np.ndarray = array("f4", 3, optional=True)
    axes: np.ndarray = array("f4", "A", optional=True)
    buttons: int = 0
    command: str = ""
    argument: str = ""
    source: str = ""
    face: int = -1
    pose: np.ndarray = array("f4", 6, optional=True)

    def check(self) -> None:
        if self.kind not in INPUT_KINDS:
            raise DecodeError(f"InputEvent.kind {self.kind!r} is not one of {', '.join(INPUT_KINDS)}")


@register
@dataclass
class Deformation(Message):
    """The user's edit as a displacement of the neutral model (docs/architecture.md "Stages", 3).

    displacement: (V, 3) float32, model space, mm (M_m - M_bar).
    static / handles / roi: anchor vertex indices, int32, of face ``face_id`` (the face last
    edited).  version grows with every solve.  Several faces: face_ids (P,) int32 and
    displacements (P, V, 3) float32 give each edited face its own; a face not listed (or no
    lists) uses ``displacement``.
    pose: (6,) float32, optional: the pose offset of face ``face_id`` (issue 18): yaw, pitch, roll
    in degrees added to the head's own angles, x, y, z in mm (camera axes), as
    facesculpt.geometry.pose_offset.PoseOffset.as_list; poses (P, 6) float32 that of each face of
    ``face_ids``. Absent or zeros: the head keeps its tracked pose.
    """

    TYPE = "Deformation"
    model_id: str = ""
    displacement: np.ndarray = array("f4", "V", 3)
    static: np.ndarray = array("i4", "S")
    handles: np.ndarray = array("i4", "H")
    roi: np.ndarray = array("i4", "R")
    version: int = 0
    face_id: int = 0
    face_ids: np.ndarray = array("i4", "P", optional=True)
    displacements: np.ndarray = array("f4", "P", "V", 3, optional=True)
    pose: np.ndarray = array("f4", 6, optional=True)
    poses: np.ndarray = array("f4", "P", 6, optional=True)

    def pose_of(self, face_id: int) -> np.ndarray:
        """(6,) float32 the pose offset of face ``face_id`` (yaw, pitch, roll deg, x, y, z mm): its
        own when ``face_ids`` and ``poses`` list it, else ``pose``, else zeros."""
        if self.face_ids is not None and self.poses is not None:
            hit = np.flatnonzero(self.face_ids == int(face_id))
            if hit.size:
                return self.poses[hit[0]]
        return np.zeros(6, np.float32) if self.pose is None else self.pose

    def displacement_of(self, face_id: int) -> np.ndarray:
        """(V, 3) the displacement of face ``face_id``: its own when listed, else ``displacement``."""
        if self.face_ids is not None and self.displacements is not None:
            hit = np.flatnonzero(self.face_ids == int(face_id))
            if hit.size:
                return self.displacements[hit[0]]
        return self.displacement


@register
@dataclass
class Diagnostics(Message):
    """Per-node figures, published about once a second on `diagnostics`.

    values: {"rate_hz": {topic: Hz}, "age_ms": {topic: ms}, "received", "dropped",
    "malformed", "published": {topic: n}, "subscribers": {topic: n connected}, "errors": n, "last_error": str,
    "stages_ms": {stage: mean ms}, "counters": {name: n}}.
    """

    TYPE = "Diagnostics"
    node: str = ""
    pid: int = 0
    values: dict = field(default_factory=dict)


@register
@dataclass
class FrameDone(Message):
    """The renderer has handled the camera frame stamped ``stamp`` (seq: that frame's seq), on
    `render/done`: an offline camera waits for it before sending the next frame.
    rendered: the face was drawn (False: the frame passed through, e.g. without a face)."""

    TYPE = "FrameDone"
    rendered: bool = False


@register
@dataclass
class FaceExpression(Message):
    """One fitted face's head pose and expression parameters, on `face/expression`.

    face_id: as FaceState.face_id.  pose: (6,) float64 yaw, pitch, roll (degrees) and the
    camera-space translation (mm).  names[i] names values[i] ((E,) float32; units in
    docs/guide/expressions.md: percent of the inter-ocular distance, eye closure 0..1).
    """

    TYPE = "FaceExpression"
    face_id: int = 0
    pose: np.ndarray = array("f8", 6)
    names: list = field(default_factory=list)
    values: np.ndarray = array("f4", "E")


@register
@dataclass
class HandLandmarks(Message):
    """The hands in one frame, on `hands/landmarks` (N = 0 when there is none).

    points: (N, 21, 3) float32: x, y in image pixels, z depth relative to the wrist in the same
    scale (smaller = nearer the camera); mediapipe's joint order (0 wrist, 1-4 thumb, 5-8 index,
    9-12 middle, 13-16 ring, 17-20 little finger, base to tip).
    scores: (N,) float32 hand presence in 0..1.
    right: (N,) float32 the probability that the hand is the person's right hand.
    rois: (N, 5) float32 crop of each hand: cx, cy, w, h (pixels), angle (radians).
    track_ids: (N,) int32 the same number for the same tracked hand across frames.
    image_size: [W, H] of the source frame.  K: (3, 3) float64 its intrinsics.
    """

    TYPE = "HandLandmarks"
    points: np.ndarray = array("f4", "N", 21, 3)
    scores: np.ndarray = array("f4", "N")
    right: np.ndarray = array("f4", "N")
    rois: np.ndarray = array("f4", "N", 5)
    track_ids: np.ndarray = array("i4", "N")
    image_size: list = field(default_factory=lambda: [0, 0])
    K: np.ndarray = array("f8", 3, 3)


@register
@dataclass
class FaceTexture(Message):
    """The texture memory of one face (latched on `face/texture`): its UV atlas, downscaled.

    image: (S, S, 3) uint8 BGR, the atlas in its own lighting (the first frames'), black where
    never seen; confidence: (S, S) uint8, how well each texel is known (0 never seen .. 255);
    texcoords: (V, 2) float32 the UV layout of the model's vertices in [0, 1] (texel
    (row, col) = (v, u) * S); model_id, face_id: whose atlas; updates: the frames it has taken
    since it was last reset (a new face).
    """

    TYPE = "FaceTexture"
    model_id: str = ""
    face_id: int = 0
    image: np.ndarray = array("u1", "S", "S", 3)
    confidence: np.ndarray = array("u1", "S", "S")
    texcoords: np.ndarray = array("f4", "V", 2)
    updates: int = 0


@register
@dataclass
class CodedKey(Message):
    """The keyframe of model-based coding (latched on `coding/key`), sent once per keyframe
    (:mod:`facesculpt.coding.fsc`).

    header: JSON text (version, fps, width, height, K, vertices, model); keyframe: (J,) uint8 the
    keyframe image's bytes (WebP); arrays: (Z,) uint8 zlib of its fit and the person's neutral
    (:func:`~facesculpt.coding.fsc.pack_key_arrays`); triangles: (T, 3) int32 the model's mesh (the
    receiver loads no model); version: this keyframe's number.
    """

    TYPE = "CodedKey"
    header: str = ""
    keyframe: np.ndarray = array("u1", "J")
    arrays: np.ndarray = array("u1", "Z")
    triangles: np.ndarray = array("i4", "T", 3)
    version: int = 0


@register
@dataclass
class CodedBasis(Message):
    """The expression basis of model-based coding (latched on `coding/basis`), sent after its key
    and again whenever the coder learns it anew.

    key_version: the key it belongs to; version: this basis's number; arrays: (Z,) uint8 zlib of
    the mean and the basis at control vertices, int8 (:func:`~facesculpt.coding.fsc.pack_basis`; the
    receiver fills them in over the key's triangles); basis_steps (C,) and
    coeff_steps (C,) float64 their quantisation steps; record: (R,) uint8 the keyframe's own
    per-frame record in this basis (the pose and expression the keyframe is rendered from).
    """

    TYPE = "CodedBasis"
    key_version: int = 0
    version: int = 0
    arrays: np.ndarray = array("u1", "Z")
    basis_steps: np.ndarray = array("f8", "C")
    coeff_steps: np.ndarray = array("f8", "C")
    record: np.ndarray = array("u1", "R")


@register
@dataclass
class CodedFrame(Message):
    """One frame of model-based coding (`coding/frame`): record (R,) uint8, the `.fsc` per-frame
    record (a face flag, the quantised pose and expression coefficients) in basis
    ``basis_version`` of key ``key_version``."""

    TYPE = "CodedFrame"
    record: np.ndarray = array("u1", "R")
    key_version: int = 0
    basis_version: int = 0
