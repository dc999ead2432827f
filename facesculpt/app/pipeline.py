"""The in-process pipeline: one frame in -> landmarks -> fit -> merge the edit -> composite -> frame out.

The graph's stages called one after the other on the same frame, in one process, with no
sockets: the renderer's ``sync`` pairing by construction (the state fitted on a frame is
rendered on that frame). ``facesculpt process`` runs it over a video; ``facesculpt bench`` times
it stage by stage. Each stage is the room's own code, the same the nodes call
(docs/architecture.md, "Stages"): :class:`LandmarkDetector`, :func:`fit_landmarks` (with a
fitter configured by a :class:`FitterConfig`, as the fitter node's), :func:`merge_deformation`,
:class:`Compositor`; the edit is an :class:`EditStack` (ARAP) solved on the fitted person's
neutral model.

Edits and the neutral. An edit (a deformer preset: handles by landmark name, model-space
offsets in mm, ROI radii) is solved once, on the neutral model of the person in the video, and
the same displacement (V, 3) mm is merged into every frame (paper Eq. 5). The neutral is learned
from the frames (facemesh: the reference averaged over the first ``neutral_frames`` frames;
SFM: the accumulated identity), so :meth:`Pipeline.calibrate` first runs landmarks + fitting over
the first frames until that neutral is complete, then :meth:`Pipeline.set_edits` solves the edit
on it. The fitter keeps what it learned (neutral, identity) for the pass that renders; its pose
filters and the landmark tracker start afresh. Same input, same options: same output, bit for bit
(frame times come from the frame index, never from the clock).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facesculpt.app.pipeline_options import options_of_old_names
from facesculpt.geometry import merge_deformation
from facesculpt.geometry.pose_offset import (
    FACE_CAMERA_LIMIT_DEG,
    FACE_CAMERA_SMOOTHING_S,
    PoseOffset,
    check_face_camera,
)
from facesculpt.nodes.camera.intrinsics import FOV_DEG, intrinsics_from_fov
from facesculpt.nodes.deformer import DeformerError, EditStack
from facesculpt.nodes.deformer.preset_format import PRESET_FORMAT, merge_presets, preset_pose, validate_preset
from facesculpt.nodes.fitter import (
    FaceFitters,
    Fitter,
    FitterConfig,
    MorphableModel,
    load_model,
    make_fitter,
    max_faces_for,
    parse_faces,
)
from facesculpt.nodes.fitter.expression import NAMES, face_expression
from facesculpt.nodes.fitter.expression_labels import (
    ExpressionLabelOptions,
    ExpressionRecogniser,
    has_expression_blendshapes,
)
from facesculpt.nodes.fitter.gaze import EyeballLearning, estimate_gaze, eye_lid_vertices
from facesculpt.nodes.fitter.stage import MIN_SCORE
from facesculpt.nodes.landmarks import LandmarkDetector
from facesculpt.nodes.landmarks.detector import FACE_OPTIONS
from facesculpt.nodes.landmarks.working_resolution import ANALYSIS_PIXELS, track_at_working_resolution
from facesculpt.nodes.renderer.compositor_options import CompositorOptions

#: Per-frame stages timed by :meth:`Pipeline.process` (ms), in order.
STAGES = ("landmarks", "fit", "merge", "render")


def load_face_model(name_or_path: str) -> MorphableModel:
    """:func:`load_model` with a clear error for the Surrey Face Model, which is not shipped: it is
    read from the shared data folder (free for non-commercial use only)."""
    try:
        return load_model(name_or_path)
    except FileNotFoundError as exc:
        if str(name_or_path) != "sfm":
            raise
        raise FileNotFoundError(
            "the 'sfm' model (the Surrey Face Model, free for non-commercial use) is read from the shared data "
            f"folder, which is missing or incomplete ({exc}); set FACESCULPT_DATA, or use --model facemesh "
            "or a MODEL.npz made by `facesculpt model import-eos`") from None


def read_preset(path: str | Path) -> dict:
    """A deformer preset file (JSON, as :meth:`EditStack.save_preset` writes), or the name of a
    shipped one (:func:`facesculpt.paths.preset_file`), as a dict; FileNotFoundError or ValueError
    naming the file when it is missing, cannot be read, is not JSON, not a JSON object or not a
    valid preset (:func:`facesculpt.nodes.deformer.preset_format.validate_preset`)."""
    import json

    from facesculpt.paths import preset_file

    path = preset_file(str(path))
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"preset {path} not found") from None
    except (OSError, ValueError) as exc:
        raise ValueError(f"cannot read preset {path}: {exc}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("edits", []), list):
        kinds = {list: "a JSON list", str: "a JSON string", int: "a JSON number", float: "a JSON number",
                 bool: "a JSON boolean", type(None): "null"}
        what = kinds.get(type(doc), "an object whose 'edits' is not a list")
        raise ValueError(f"preset {path} is {what}, not a deformer preset (a JSON object with 'format', "
                         f"'version' and a list of 'edits', as the window's S key saves)")
    if doc.get("format") != PRESET_FORMAT:
        raise ValueError(f"preset {path} is a JSON object without \"format\": \"{PRESET_FORMAT}\", not a deformer "
                         f"preset (a JSON object with 'format', 'version' and a list of 'edits', as the window's "
                         f"S key saves)")
    try:
        validate_preset(doc)
    except DeformerError as exc:
        raise ValueError(f"preset {path}: {exc}") from None
    return doc


@dataclass
class FrameResult:
    """One processed frame.

    image: (H, W, 3) uint8 BGR, the composited frame (the input itself, unchanged, without a
    face); fit: the first fitted face's :class:`FitResult` or None (no face, or the fit was
    refused); fits: face key -> :class:`FitResult` of every fitted face (the key is 0 for
    ``faces="largest"``, else the face's track id); timings_ms: stage -> ms for the stages that
    ran (:data:`STAGES`, summed over faces); render_ms: the compositor's own stages (camera,
    texture, draw, readback, masks, inpaint, composite); deformed: face key -> (V, 3) camera-space
    mm, each edited face's mesh as drawn (the edit merged in, a pose edit's turn included), for the
    edited depth (:mod:`facesculpt.nodes.renderer.edited_depth`)."""

    image: np.ndarray
    fit: object | None
    timings_ms: dict[str, float] = field(default_factory=dict)
    render_ms: dict[str, float] = field(default_factory=dict)
    fits: dict = field(default_factory=dict)
    deformed: dict = field(default_factory=dict)


class Pipeline:
    """Landmarks, fitting, the edit and compositing of one video, frame by frame, in-process.

    model: "facemesh", "sfm" or a .npz path (or a :class:`MorphableModel`); fit: the fitter's
    options (:class:`FitterConfig`, the fitter node's defaults; its ``neutral_frames`` are also the
    frames :meth:`calibrate` runs); render: the compositor's
    (:class:`~facesculpt.nodes.renderer.compositor_options.CompositorOptions`; its ``atlas`` and
    ``plate`` are set from the modes below); threads: onnxruntime intra-op threads of each
    network; fov_deg: horizontal field of view of the pinhole K given to the fitter (as the camera
    node does; the fitter then fits in perspective); min_score: faces below this landmark score are
    not fitted; faces: which faces are fitted and edited, "largest", "all" or a face number from 1
    (:func:`facesculpt.nodes.fitter.parse_faces`), each with its own fitter and neutral;
    plate: "on" keeps a background plate and takes what an edit uncovers from it where it was seen
    (issue 16, :mod:`facesculpt.nodes.renderer.background_plate`), "off" not; atlas: the face's texture memory (issue 16),
    "off", "on" (learned and blended where the frame sees the edited surface badly) or "learn"
    (learned only, for :meth:`texture`), in the model's UV layout (:meth:`uv_layout`); detector: a :class:`LandmarkDetector` to
    reuse (reset here), else one is made; analysis_pixels: landmarks run on a copy of a larger
    frame halved until it holds at most this many pixels, their points carried back to the frame's
    (:mod:`facesculpt.nodes.landmarks.working_resolution`; 0: on the frame itself); fitting and
    compositing work at the frame's own resolution; pose: a :class:`PoseOffset` every fitted head is
    turned and moved by (issue 18; the face's motion is carried over the head around it); face_camera:
    0-1, each frame turns every face that share of the way toward looking into the camera (at most
    ``face_camera_limit_deg`` in yaw and pitch; the direction to the camera smoothed over
    ``face_camera_smoothing_s``), on top of
    ``pose``; keyframes: "on" keeps views of each face at the poses it shows and renders turned
    surface from the closest one where it sees it better than the frame (image-based rendering,
    :mod:`facesculpt.nodes.renderer.keyframe_views`), "auto" (the default) does so when a pose edit
    is asked for (``pose``, ``face_camera`` or a preset's pose), "off" never; expression: give
    each fit its expression parameters (``fit.expression``, :mod:`facesculpt.nodes.fitter.expression`)
    and the expression recognised from them (``fit.expression_label``,
    :mod:`facesculpt.nodes.fitter.expression_labels`, with ``expression_labels``, an
    :class:`ExpressionLabelOptions`; None: its defaults, the resting face over ``fit``'s
    ``neutral_frames``); False: None, and their cost saved. The old keywords ``neutral_frames``, ``iterations``,
    ``rotation_prior_px``, ``refine``, ``inpaint``, ``feather_px``, ``dilate_px``, ``interpolation``
    and ``outline_band`` still work for one release, with a DeprecationWarning
    (:mod:`.pipeline_options`). The GL context is made here; call
    :meth:`close` (or use ``with``) to free it. pose_limit: each frame draws only the share of its pose
    edit that what is known of the surface it reveals allows (issue 51,
    :mod:`facesculpt.nodes.renderer.pose_limit`; ``pose_limiter.lowest`` and ``.reduced`` say how
    far and how often it was reduced); False: the whole edit always. gaze: run the iris network on
    each found face's eyes (``FrameResult``'s timings "irises") and give each fit its gaze
    (``fit.gaze``, :mod:`facesculpt.nodes.fitter.gaze`, each face's eyeballs learned over its first
    frames; timings "gaze"). K: the colour camera's (3, 3)
    intrinsics at the frame's size, px (an RGB-D recording's own); None: a pinhole of ``fov_deg``.
    Frames may come with an aligned depth image (:class:`~facesculpt.nodes.fitter.depth_fitting.DepthImage`):
    each fit is then refined on it (issue 49, :mod:`facesculpt.nodes.fitter.depth_fitting`).
    """

    def __init__(self, model: str | MorphableModel = "facemesh", *, fit: FitterConfig | None = None,
                 render: CompositorOptions | None = None, threads: int = FACE_OPTIONS.threads, fov_deg: float = FOV_DEG,
                 min_score: float = MIN_SCORE, models_dir: str | Path | None = None,
                 faces: str | int = "largest", detector: LandmarkDetector | None = None, atlas: str = "off",
                 plate: str = "off", analysis_pixels: int = ANALYSIS_PIXELS,
                 pose: PoseOffset | None = None, face_camera: float = 0.0, keyframes: str = "auto",
                 face_camera_limit_deg: float = FACE_CAMERA_LIMIT_DEG,
                 face_camera_smoothing_s: float = FACE_CAMERA_SMOOTHING_S, expression: bool = True,
                 pose_limit: bool = True, gaze: bool = False, expression_labels: ExpressionLabelOptions | None = None,
                 K: np.ndarray | None = None, **deprecated):
        fit, render = options_of_old_names(fit or FitterConfig(), render or CompositorOptions(), deprecated)
        self.model = model if isinstance(model, MorphableModel) else load_face_model(model)
        self.selection = parse_faces(faces)
        if detector is None:
            detector = LandmarkDetector(models_dir=models_dir, threads=threads)
        detector.reset()  # a detector reused from another video starts afresh
        detector.max_faces = max_faces_for(self.selection)
        self.detector = detector
        self.analysis_pixels = int(analysis_pixels)
        self.fov_deg = float(fov_deg)
        self.fitter_config = fit
        self.neutral_frames = fit.neutral_frames
        self.min_score = float(min_score)
        if plate not in ("off", "on"):
            raise ValueError(f"plate must be off or on, got {plate!r}")
        if keyframes not in ("off", "on", "auto"):
            raise ValueError(f"keyframes must be off, on or auto, got {keyframes!r}")
        if atlas not in ("off", "on", "learn"):
            raise ValueError(f"atlas must be off, on or learn, got {atlas!r}")
        self.render_options = dataclasses.replace(render, atlas=atlas != "off", atlas_blend=atlas == "on",
                                                  plate=plate == "on")
        self.segmenter = None
        if plate == "on":  # the plate learns nothing where a person is (their hair, neck, shoulders)
            from facesculpt.nodes.renderer.person_segmentation import PersonSegmenter

            self.segmenter = PersonSegmenter(models_dir, threads)
        self.expression = bool(expression)
        self.irises = None
        if gaze:
            from facesculpt.nodes.landmarks.irises import IrisDetector

            self.irises = IrisDetector(models_dir or "", threads)
        self.eyeballs: dict[int, EyeballLearning] = {}  # face key -> what is learned of its eyes
        self.label_options = expression_labels or ExpressionLabelOptions(baseline_frames=self.neutral_frames)
        self.recognisers: dict[int, ExpressionRecogniser] = {}  # face key -> its expressions recognised
        if self.expression and self.label_options.source == "blendshapes" and not has_expression_blendshapes(
                self.model.expression_names):
            raise ValueError("expressions recognised from blendshapes need a model whose blendshapes are named for "
                             "the six basic expressions (the Surrey Face Model's), and this one has none")
        if self.expression:
            ExpressionRecogniser(self.label_options)   # a bad weights file: one sentence now, not at the first face
        self.keyframes = keyframes
        check_face_camera(face_camera, face_camera_limit_deg, face_camera_smoothing_s)
        self.pose = pose if pose is not None else PoseOffset()
        self.face_camera, self.face_camera_limit_deg = float(face_camera), float(face_camera_limit_deg)
        self.face_camera_smoothing_s = float(face_camera_smoothing_s)
        self._pose_edits = None   # the renderer's PoseEdits (made with the compositor's package, on first use)
        self.pose_limit, self.pose_limiter = bool(pose_limit), None
        self._uv = None
        self.faces: FaceFitters | None = None
        self.compositor = None
        self.size: tuple[int, int] | None = None
        self.K: np.ndarray | None = None if K is None else np.asarray(K, np.float64).reshape(3, 3)
        self.presets: list[tuple[int | None, dict]] = []  # (face key or None: every face, preset)
        self.displacements: dict[int, np.ndarray | None] = {}  # face key -> (V, 3) mm, solved once per face
        self.fitted_frames = 0  # frames with at least one fitted face
        self.fitted_per_face: dict[int, int] = {}
        self.track_ids_seen: set[int] = set()  # the detector's track ids (face N is track N - 1) found so far

    # -- set-up per frame size --------------------------------------------------------------------
    def _prepare(self, width: int, height: int) -> None:
        if self.size == (width, height):
            return
        if self.size is not None:
            raise ValueError(f"frame size changed from {self.size[0]}x{self.size[1]} to {width}x{height}")
        self.size = (width, height)
        if self.K is None:
            self.K = intrinsics_from_fov(width, height, self.fov_deg)
        self.faces = FaceFitters(lambda: make_fitter(self.model, self.fitter_config, self.size, self.K),
                                 self.selection)

    def _compositor(self):
        if self.compositor is None:
            from facesculpt.nodes.renderer import Compositor

            turns = not self.pose.is_zero or self.face_camera > 0 or any(p.get("pose") for _, p in self.presets)
            keyframes = self.keyframes == "on" or (self.keyframes == "auto" and turns)
            self.compositor = Compositor(self.size[0], self.size[1], self.render_options, keyframes=keyframes,
                                         segmenter=self.segmenter)
        return self.compositor

    @property
    def fitter(self) -> Fitter | None:
        """The first face's fitter (the only one for ``faces="largest"``), None before any face."""
        return None if self.faces is None else self.faces.first

    # -- the stages -------------------------------------------------------------------------------
    def fit_faces(self, frame_bgr: np.ndarray, stamp_s: float, timings: dict | None = None, depth=None) -> dict:
        """Landmarks and fit of one frame (H, W, 3) uint8 BGR at time ``stamp_s`` (s), refined on
        its aligned ``depth`` image when given (a :class:`DepthImage`). Returns face key ->
        :class:`FitResult` for the selected faces that were fitted ({} without one)."""
        h, w = frame_bgr.shape[:2]
        self._prepare(w, h)
        timings = {} if timings is None else timings
        t0 = time.perf_counter()
        found = track_at_working_resolution(self.detector, frame_bgr, self.analysis_pixels)
        timings["landmarks"] = (time.perf_counter() - t0) * 1e3
        self.track_ids_seen.update(f.track_id for f in found)
        if not found:
            return {}
        eyes = self._find_irises(frame_bgr, found, timings)
        t0 = time.perf_counter()
        fits = {}
        for face in self.faces.fit([f.points for f in found], [f.score for f in found],
                                   [f.track_id for f in found], stamp_s, self.min_score, image=frame_bgr,
                                   depth=depth):
            if face.outcome.fit is not None:
                fit = face.outcome.fit
                fitter = self.faces.fitters[face.key]
                if self.expression:
                    fit.expression = face_expression(fit, fitter.model, fitter.neutral, found[face.index].points)
                    recogniser = self.recognisers.setdefault(face.key, ExpressionRecogniser(self.label_options))
                    fit.expression_label = recogniser.update(stamp_s, fit.expression, NAMES, fit.beta,
                                                             fitter.model.expression_names, fit.yaw_pitch_roll[:2])
                if eyes:
                    t1 = time.perf_counter()
                    learning = self.eyeballs.setdefault(face.key, EyeballLearning())
                    fit.gaze = estimate_gaze(fit, eye_lid_vertices(fitter.model), *eyes[face.index], learning,
                                             found[face.index].points)
                    timings["gaze"] = timings.get("gaze", 0.0) + (time.perf_counter() - t1) * 1e3
                fits[face.key] = fit
                self.fitted_per_face[face.key] = self.fitted_per_face.get(face.key, 0) + 1
        timings["fit"] = (time.perf_counter() - t0) * 1e3 - timings.get("gaze", 0.0)
        self.fitted_frames += bool(fits)
        return fits

    def _find_irises(self, frame_bgr: np.ndarray, found: list, timings: dict) -> list | None:
        """Each found face's (irises (2, 5, 3), lids (2, 16, 3)) pixels, None without ``gaze``."""
        if self.irises is None:
            return None
        t0 = time.perf_counter()
        eyes = [self.irises.find(frame_bgr, f.points) for f in found]
        timings["irises"] = (time.perf_counter() - t0) * 1e3
        return eyes

    def fit_frame(self, frame_bgr: np.ndarray, stamp_s: float, timings: dict | None = None):
        """:meth:`fit_faces`, the first fitted face only: its :class:`FitResult` or None."""
        fits = self.fit_faces(frame_bgr, stamp_s, timings)
        return fits[min(fits)] if fits else None

    def analyse(self, frame_bgr: np.ndarray, stamp_s: float, depth=None) -> tuple[dict, dict]:
        """Landmarks, fit (on the frame's aligned ``depth`` image when given, a :class:`DepthImage`)
        and each fitted face's edit (solved now if new) of one frame: the part of
        :meth:`process` that carries state from frame to frame. Returns (face key -> FitResult,
        timings ms). :meth:`compose` then renders it; a second thread may compose frame i while
        this analyses frame i + 1."""
        if not (isinstance(frame_bgr, np.ndarray) and frame_bgr.dtype == np.uint8 and frame_bgr.ndim == 3
                and frame_bgr.shape[2] == 3):
            raise ValueError("frames must be (H, W, 3) uint8 BGR")
        if self.compositor is not None:  # what the compositor needs of the frame alone starts now
            self.compositor.prefetch(frame_bgr)
        timings: dict[str, float] = {}
        fits = self.fit_faces(frame_bgr, stamp_s, timings, depth)
        for key, fit in fits.items():
            self.displacement_of(key)
            fit.pose_edit = self._pose_edit(key, fit, stamp_s)
            fit.pose_stamp = stamp_s
        return fits, timings

    def _pose_edit(self, key: int, fit, stamp_s: float) -> tuple[PoseOffset, np.ndarray] | None:
        """Face ``key``'s pose edit on the frame at ``stamp_s`` (s): (``pose``, plus the ``pose`` of
        the presets that edit it, plus, with ``face_camera``, the turn toward the camera;
        the head's pivot (3,) model mm, from its neutral now: compose may run while the next
        frame's fit updates it); None when zero."""
        offset = self.pose
        for face, preset in self.presets:  # a preset's own "pose" turns the faces it edits
            if face is None or face == key:
                offset = offset + (preset_pose(preset) or PoseOffset())
        if self._pose_edits is None:
            from facesculpt.nodes.renderer.pose_edit import PoseEdits

            self._pose_edits = PoseEdits(self.face_camera, self.face_camera_limit_deg, self.face_camera_smoothing_s)
        return self._pose_edits.edit(fit, offset, self.neutral_of(key), int(round(stamp_s * 1e9)), face=key)

    def _turn(self, key: int, fit, deformed: np.ndarray) -> np.ndarray:
        """Face ``key``'s ``deformed`` (V, 3) mesh turned by its pose edit: all of it, or with
        ``pose_limit`` the share that what is known of the surface it reveals allows (the
        frame's own view and the compositor's stored views of the face)."""
        if not self.pose_limit:
            return self._pose_edits.apply(deformed, fit, fit.pose_edit)
        from facesculpt.nodes.renderer.pose_limit import PoseLimiter, turn_within_limits

        if self.pose_limiter is None:
            self.pose_limiter = PoseLimiter()
        return turn_within_limits(self.pose_limiter, key, getattr(fit, "pose_stamp", 0.0), fit, deformed,
                                  fit.pose_edit, self.model.triangles, getattr(self.compositor, "views", None))[0]

    def compose(self, frame_bgr: np.ndarray, fits: dict, timings: dict,
                keep_mask: np.ndarray | None = None) -> FrameResult:
        """The frame with every fitted face of ``fits`` (from :meth:`analyse`) merged with its edit
        and composited; the GL work, in the thread that made this pipeline's compositor.
        ``keep_mask``: optional (H, W) bool pixels kept from the input (hands in front of the face,
        :func:`facesculpt.geometry.hand_regions.hand_region_mask`)."""
        if not fits:
            return FrameResult(frame_bgr, None, timings)
        out, render_ms, drawn = frame_bgr, {}, {}
        timings["merge"] = timings["render"] = 0.0
        for key, fit in fits.items():
            t0 = time.perf_counter()
            deformed = fit.vertices
            displacement = self.displacements.get(key)
            if displacement is None and self.presets:
                continue  # other faces are edited, not this one: its pixels stay the input's
            if displacement is not None:
                deformed = merge_deformation(fit.vertices, fit.R, fit.scale, displacement)
            if fit.pose_edit is not None:
                deformed = self._turn(key, fit, deformed)
            drawn[key] = deformed
            timings["merge"] += (time.perf_counter() - t0) * 1e3
            t0 = time.perf_counter()
            compositor = self._compositor()
            out = compositor.render(out, fit.vertices, fit.projected, self.model.triangles, deformed,
                                    keep_mask=keep_mask, uv=self.uv_layout(), face_key=key,
                                    head_motion=fit.pose_edit is not None)
            timings["render"] += (time.perf_counter() - t0) * 1e3
            for k, v in compositor.timings.items():
                if k != "total":
                    render_ms[k] = render_ms.get(k, 0.0) + v
        return FrameResult(out, fits[min(fits)], timings, render_ms, fits, drawn)

    def uv_layout(self) -> np.ndarray | None:
        """(V, 2) float32 texture coordinates of the model (:func:`uv_layout`: its own, or a
        frontal projection of its mean); None with the atlas off."""
        if not self.render_options.atlas:
            return None
        if self._uv is None:
            from facesculpt.nodes.renderer.texture_atlas import uv_layout

            self._uv = uv_layout(self.model.mean.reshape(-1, 3), self.model.texcoords)
        return self._uv

    def texture(self, key: int | None = None) -> np.ndarray | None:
        """The atlas of face ``key`` (default: the first face that has one) as (S, S, 3) uint8 BGR
        in its own lighting, in the model's UV layout; None when there is none."""
        atlases = {} if self.compositor is None else self.compositor.atlases
        if not atlases:
            return None
        atlas = atlases.get(key) if key is not None else atlases[min(atlases)]
        return None if atlas is None or atlas.updates == 0 else atlas.image()

    def process(self, frame_bgr: np.ndarray, stamp_s: float, keep_mask: np.ndarray | None = None) -> FrameResult:
        """One frame through every stage; each face's edit (if any) merged into it; ``keep_mask``
        as in :meth:`compose`."""
        return self.compose(frame_bgr, *self.analyse(frame_bgr, stamp_s), keep_mask=keep_mask)

    # -- the neutral and the edit -----------------------------------------------------------------
    def neutral_of(self, key: int | None = None) -> np.ndarray:
        """(V, 3) float32 the neutral model of face ``key`` (None: the first face), model space
        (mm); the model's mean before that face was fitted."""
        if key is None:
            fitter = self.fitter
        else:
            fitter = self.faces.fitters.get(key) if self.faces is not None else None
        return fitter.neutral if fitter is not None else self.model.mean

    @property
    def neutral(self) -> np.ndarray:
        """(V, 3) float32 the first fitted person's neutral model, model space (mm)."""
        return self.neutral_of(None)

    @property
    def neutral_complete(self) -> bool:
        """The neutral of every face seen will not change much more: the dense reference is
        frozen, or (sparse) the identity has seen ``neutral_frames`` fitted frames."""
        if self.faces is None or not self.faces.fitters:
            return False
        return all(f.neutral_ready and self.fitted_per_face.get(k, 0) >= self.neutral_frames
                   for k, f in self.faces.fitters.items())

    def calibrate(self, frames: Iterable[np.ndarray], fps: float, progress=None) -> int:
        """Landmarks + fitting over ``frames`` (the video's first frames, in order; each an image, or
        an (image, :class:`DepthImage` or None) pair) until the neutral
        is complete or the frames run out; returns the frames read. The tracker is then reset (the
        frames that follow start from the video's first frame again, and its faces get the same
        track ids); the fitters keep the neutrals."""
        read = 0
        for frame in frames:
            frame, depth = frame if isinstance(frame, tuple) else (frame, None)
            self.fit_faces(frame, read / fps, depth=depth)
            read += 1
            if progress is not None:
                progress(read)
            if self.neutral_complete:
                break
        self.detector.reset()
        if self.faces is not None:
            self.faces.reset_tracking()
        return read

    def edit_stack(self, key: int | None = None, **options) -> EditStack:
        """An :class:`EditStack` on the neutral of face ``key`` (None: the first face), with the
        model's landmark names; ``options`` go to it (roi_radius, iterations, tolerance, ...)."""
        m = self.model
        return EditStack(self.neutral_of(key), m.triangles, list(m.landmark_names), m.landmark_vertices, **options)

    def set_edits(self, preset: dict | None, face: int | None = None) -> np.ndarray | None:
        """Edit every face (``face`` None) or the face with key ``face`` with a deformer preset
        (dict): solved once per face on its neutral (now for the faces fitted so far, on first
        sight for the others) and merged into each of its frames. Presets for a face accumulate
        after those for every face; ``None`` drops all edits. Returns the first face's
        displacement (V, 3) mm, or None."""
        if preset is None:
            self.presets, self.displacements = [], {}
            return None
        self.presets.append((face, preset))
        self.displacements = {}
        for key in list(self.faces.fitters) if self.faces is not None else []:
            self.displacement_of(key)
        return self.displacement

    def displacement_of(self, key: int) -> np.ndarray | None:
        """(V, 3) float32 mm: the edit of face ``key``, solved on its neutral when first asked for;
        None when no preset applies to it."""
        if key not in self.displacements:
            presets = [p for k, p in self.presets if k is None or k == key]
            if not presets:
                self.displacements[key] = None
            else:
                stack = self.edit_stack(key)
                stack.apply_preset(merge_presets(presets))
                self.displacements[key] = stack.settle().astype(np.float32)
        return self.displacements[key]

    @property
    def displacement(self) -> np.ndarray | None:
        """The first face's edit (V, 3) float32 mm, or None without an edit or a fitted face."""
        if not self.presets:
            return None
        key = min(self.faces.fitters) if self.faces is not None and self.faces.fitters else 0
        return self.displacement_of(key)

    def close(self) -> None:
        if self.compositor is not None:
            self.compositor.release()
            self.compositor = None

    def __enter__(self) -> Pipeline:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
