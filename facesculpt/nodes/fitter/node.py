"""The fitter node: ``face/landmarks`` -> ``face/state``, ``face/expression`` and ``face/gaze``, and ``face/model``
(latched).
With ``refine=appearance or pose`` it also takes ``camera/image``: each fit is refined on its frame's
pixels (:mod:`.appearance_refiner`, issue 20); a fit whose frame did not arrive is not refined.
With ``depth=on`` it keeps ``camera/image``'s depth images by stamp and refines each fit on its
frame's (:mod:`.depth_fitting`, issue 49); without one, the fit is the landmarks' alone.

A thin shell over stage 2, :func:`facesculpt.nodes.fitter.fit_landmarks` (docs/architecture.md,
"Stages"), which the in-process pipeline calls too. The model is the ``model`` param:
``facemesh`` (built-in, dense: the 468 network points are fitted directly) or a ``.npz`` made by
``facesculpt model import-eos`` (sparse: the 468 points are reduced to iBUG-68 with the landmark
node's mapping and fitted with ids 1..68). ``face/model`` carries the neutral the deformer works
on: the model mean, then the learned reference of this person (dense: the mean of the first
frames; sparse: the accumulated identity) — published when it changes, at most every
``model_period_s`` seconds while it is still being learned. No face, too few valid landmarks or
any other refusal: an empty state for that frame (0 vertices: the renderer's "no face", so a
renderer pairing frames with states never waits for it), a counter in diagnostics, never an
exception. ``face/expression`` is computed and sent only while something subscribes to it; it
carries the expression recognised too (:mod:`.expression_labels`, ``labels_*`` params).
``face/gaze`` (:mod:`.gaze`) is sent for every fitted face whose landmarks carry irises (the
landmarks node's ``irises=true``); each face's eyeballs are learned over its first frames.
"""

from __future__ import annotations

from collections import OrderedDict
from functools import partial

import numpy as np

from facesculpt.msgs import FaceExpression, FaceGaze, FaceLandmarks, FaceModel, FaceState, Image, InputEvent
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import ConfigurationError, Param, Renamed, option_params
from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE, LATCHED

from .config import FitterConfig
from .corrections import LandmarkCorrections, fit_id, ibug68_points
from .depth_fitting import DepthImage
from .expression import NAMES, face_expression, head_pose
from .expression_labels import ExpressionLabelOptions, ExpressionRecogniser, has_expression_blendshapes
from .faces import FaceFitters, parse_faces
from .fit_camera import FitCamera
from .fitter import Fitter
from .fitter_factory import make_fitter
from .gaze import EyeballLearning, Gaze, estimate_gaze, eye_lid_vertices
from .model import MorphableModel
from .model_loading import load_model
from .result import FitError
from .stage import StageOptions


def valid_intrinsics(K) -> bool:
    K = np.asarray(K, np.float64)
    return K.shape == (3, 3) and bool(np.isfinite(K).all()) and K[0, 0] > 0 and K[1, 1] > 0 and abs(K[2, 2] - 1) < 1e-6


#: The :class:`FitterConfig` fields the node takes as parameters (the others keep their defaults).
FITTER_PARAMS = ("iterations", "tracking_iterations", "projection", "shape_lambda", "expression_lambda", "outline",
                 "smoothing", "smooth_min_cutoff", "neutral_frames", "rotation_prior_px", "refine")
#: The :class:`ExpressionLabelOptions` fields the node takes, each as ``labels_<field>``.
_LABEL_FIELDS = ("window_s", "neutral_below", "switch_margin", "source", "weights")
_LABEL_PARAMS = tuple(f"labels_{k}" for k in _LABEL_FIELDS)


class FitterNode(Node):
    """Fits the face model to face/landmarks: publishes face/state, face/expression and face/model."""

    NAME = "fitter"
    TOPICS = ("face/state", "face/model", "face/expression", "face/gaze", "face/landmarks", "input/events", "camera/image")
    PARAMS = {
        "model": Param("facemesh", "\"facemesh\" (built in), or a .npz model file (facesculpt model import-eos)"),
        # the fitter's own options, declared once in FitterConfig
        **option_params(FitterConfig(), FITTER_PARAMS),
        "min_cutoff": Renamed("smooth_min_cutoff"),
        "model_period_s": Param(1.0, "least time between face/model updates while the neutral is learned, s",
                                range=(0.0, 3600.0)),
        "model_change_mm": Param(2.0, "sparse, once learned (2 x neutral_frames frames): republish when a "
                                      "landmark vertex moved this much, mm", range=(0.0, None)),
        **option_params(StageOptions(), ("min_score",)),
        "faces": Param("largest", "which faces to fit: largest, all, or a face number from 1 (numbered from the "
                                  "left as first seen; the landmarks node's max_faces must cover them)"),
        "depth": Param("off", "on: refine each fit on its frame's aligned depth image (camera/image of an RGB-D "
                              "camera, docs/guide/depth-cameras.md; perspective only); off: no depth",
                       choices=("off", "on")),
        **option_params(ExpressionLabelOptions(), _LABEL_PARAMS, {f"labels_{k}": k for k in _LABEL_FIELDS}),
    }
    #: Frames kept for the landmarks that have not arrived yet (refine=appearance or pose).
    FRAMES_KEPT = 8

    def setup(self):
        self.state_pub = self.advertise("face/state", FaceState)
        self.model_pub = self.advertise("face/model", FaceModel, qos=LATCHED)
        self.expression_pub = self.advertise("face/expression", FaceExpression)
        self.gaze_pub = self.advertise("face/gaze", FaceGaze)
        self.eyeballs: dict[int, EyeballLearning] = {}  # face key -> what is learned of its eyes
        self.subscribe("face/landmarks", FaceLandmarks, self.on_landmarks)
        self.subscribe("input/events", InputEvent, self.on_event, qos=EVENTS)
        self.frames: OrderedDict[int, np.ndarray] = OrderedDict()   # stamp -> camera frame (refine)
        self.waiting: FaceLandmarks | None = None   # landmarks whose frame has not come (refine)
        self.depths: OrderedDict[int, DepthImage] = OrderedDict()   # stamp -> depth image (depth=on)
        if self.params.refine != "off" or self.params.depth == "on":
            # every frame: the one the landmarks come from must not have been replaced by a newer one
            self.subscribe("camera/image", Image, self.on_image, qos=EVERY_MESSAGE)
        self.corrections: dict[int, LandmarkCorrections] = {}  # face key -> its landmark corrections
        self.last_fits: dict = {}  # face key -> its last FitResult
        self.last_points: dict = {}  # face key -> its detected points (468, 3) px in that frame
        self.recognisers: dict[int, ExpressionRecogniser] = {}  # face key -> its expressions recognised
        self.label_options = ExpressionLabelOptions(
            baseline_frames=self.params.neutral_frames,
            **{k: getattr(self.params, f"labels_{k}") for k in _LABEL_FIELDS})
        self.model: MorphableModel | None = None
        self.faces: FaceFitters | None = None
        self.camera_key = None
        try:
            self.selection = parse_faces(self.params.faces)
        except ValueError as exc:
            raise ConfigurationError(f"fitter: {exc}") from None
        self.model_version = 0
        self.published_neutral: np.ndarray | None = None
        self.published_neutrals: dict[int, np.ndarray] = {}  # face -> its neutral last published
        self.last_model_publish = -np.inf
        self.final_faces: set[int] = set()  # faces whose complete dense reference went out
        try:
            self.model = load_model(self.params.model)
        except Exception as exc:  # missing setup files, bad .npz: running on would fit nothing
            raise ConfigurationError(f"fitter: cannot load model {self.params.model!r}: {exc}") from None
        if self.params.labels_source == "blendshapes" and not has_expression_blendshapes(self.model.expression_names):
            raise ConfigurationError(f"fitter: labels_source=blendshapes needs a model with blendshapes named for the "
                                     f"six basic expressions, and {self.params.model!r} has none")
        try:
            ExpressionRecogniser(self.label_options)   # the learned weights read now, not at the first face
        except ValueError as exc:
            raise ConfigurationError(f"fitter: {exc}") from None
        self.publish_model(self.model.mean, stamp=0)

    @property
    def fitter(self) -> Fitter | None:
        """The first face's fitter (the only one with faces=largest); None before a face."""
        return None if self.faces is None else self.faces.first

    # -- model ---------------------------------------------------------------------------------
    def publish_model(self, neutral: np.ndarray, stamp: int) -> None:
        """face/model with ``neutral`` (V, 3) mm; with a selection other than "largest", every
        fitted face's own neutral too (``face_ids``, ``neutrals``)."""
        m = self.model
        self.model_version += 1
        per_face = {}
        if self.selection != "largest" and self.faces is not None:
            per_face = {k: np.asarray(f.neutral, np.float32) for k, f in sorted(self.faces.fitters.items())}
        self.model_pub.publish(FaceModel(
            stamp=int(stamp), model_id=m.model_id, vertices=np.asarray(neutral, np.float32),
            triangles=m.triangles.astype(np.int32), landmark_names=list(m.landmark_names),
            landmark_vertices=m.landmark_vertices.astype(np.int32), units=m.units, version=self.model_version,
            face_ids=np.array(list(per_face), np.int32) if per_face else None,
            neutrals=np.stack(list(per_face.values())) if per_face else None,
        ))
        self.published_neutral = np.array(neutral, np.float32)
        self.published_neutrals = {k: v.copy() for k, v in per_face.items()}
        if self.selection == "largest" and self.faces is not None:
            self.published_neutrals = {k: self.published_neutral for k in self.faces.fitters}
        self.count("model_published")

    def _neutral_change(self, f: Fitter, published: np.ndarray | None) -> tuple[float, float, bool]:
        """(how far the fitter's neutral moved since ``published``, mm; the threshold that calls
        for a new face/model; whether its dense reference is complete)."""
        neutral = f.neutral
        done = f.model.dense and f.neutral_ready
        learned = not f.model.dense and f.frames_fitted >= 2 * self.params.neutral_frames
        threshold = self.params.model_change_mm if learned else 0.5
        if published is None:
            return np.inf, threshold, done
        if learned:
            # Judge the face itself (its landmark vertices, measured per vertex), not the skull
            # behind it, which the landmarks barely constrain (it swings much more).
            change = neutral[f.model.landmark_vertices] - published[f.model.landmark_vertices]
            return float(np.linalg.norm(change, axis=1).max()), threshold, done
        return float(np.abs(neutral - published).max()), threshold, done

    def publish_gaze(self, msg: FaceLandmarks, fitted: list) -> None:
        """``face/gaze`` of each fitted face from its landmarks' irises and lids."""
        if np.shape(msg.irises)[0] != np.shape(msg.points)[0] or np.shape(msg.eye_lids)[0] != np.shape(msg.points)[0]:
            self.count("bad_irises")
            return
        for f in fitted:
            fitter = self.faces.fitters[f.key]
            try:
                lid_vertices = eye_lid_vertices(fitter.model)
            except ValueError as exc:
                self.count("no_gaze")
                self.last_error = str(exc)
                return
            with self.stage("gaze"):
                learning = self.eyeballs.setdefault(f.key, EyeballLearning())
                gaze = estimate_gaze(f.outcome.fit, lid_vertices, msg.irises[f.index], msg.eye_lids[f.index], learning,
                                     msg.points[f.index] if np.shape(msg.points)[1] == 468 else None)
            self.gaze_pub.publish(gaze_message(gaze, msg.stamp, msg.frame_id, f.key))

    def maybe_publish_model(self, stamp: int, now_s: float) -> None:
        """Publish the learned neutrals when one moved by more than 0.5 mm somewhere, at most every
        ``model_period_s``; always once when a face's dense reference is complete. A sparse identity
        keeps accumulating evidence (and jitter) after it has been learned: from 2 x
        ``neutral_frames`` frames on, only a landmark vertex moving past ``model_change_mm`` is
        republished, since each new neutral makes the deformer solve the edits again (and the
        edited face wobble)."""
        completes, moves = False, False
        for key, f in self.faces.fitters.items():
            if key in self.final_faces:
                continue
            # one face: its neutral against the last published one (at first the model's mean)
            default = self.published_neutral if self.selection == "largest" else None
            moved, threshold, done = self._neutral_change(f, self.published_neutrals.get(key, default))
            completes |= done and moved > 0
            moves |= moved > threshold
            if done and moved == 0:
                self.final_faces.add(key)
        if completes or (moves and now_s - self.last_model_publish >= self.params.model_period_s):
            self.publish_model(self.fitter.neutral, stamp)
            self.last_model_publish = now_s
            self.final_faces |= {k for k, f in self.faces.fitters.items() if f.model.dense and f.neutral_ready}

    # -- landmark corrections (seed 002) -------------------------------------------------------
    def on_event(self, msg: InputEvent) -> None:
        """correct_landmark: put iBUG landmark ``argument`` of the face under (or named by) the
        event at pixel (x, y), for this and every later frame; clear_corrections: forget them."""
        if msg.kind != "command" or msg.command not in ("correct_landmark", "clear_corrections"):
            return
        faces = [msg.face] if msg.face >= 0 else list(self.last_fits)
        if msg.command == "clear_corrections":
            for key in faces:
                self.corrections.pop(key, None)
            self.count("corrections_cleared")
            return
        try:
            if not (np.isfinite(msg.x) and np.isfinite(msg.y)):
                raise ValueError("correct_landmark needs the pixel x, y to put the landmark at")
            key = self._face_near(faces, msg.x, msg.y)
            fitter = self.faces.fitters[key]
            self.corrections.setdefault(key, LandmarkCorrections()).set(
                fit_id(msg.argument, fitter.model.dense), (msg.x, msg.y), self.last_fits[key], fitter.model,
                self.last_points.get(key))
        except (ValueError, KeyError) as exc:
            self.count("bad_correction")
            self.last_error = f"correct_landmark: {exc}"
            self.log.warning("%s", self.last_error)
            return
        self.count("landmark_corrected")

    def _face_near(self, faces: list[int], x: float, y: float) -> int:
        """The fitted face (of ``faces``) whose fitted points come nearest pixel (x, y)."""
        near = [(float(np.min(np.linalg.norm(self.last_fits[k].projected - [x, y], axis=1))), k)
                for k in faces if k in self.last_fits]
        if not near:
            raise ValueError("no fitted face to correct yet")
        return min(near)[1]

    # -- frames --------------------------------------------------------------------------------
    def on_image(self, msg: Image) -> None:
        """Keep the frame (refine=appearance or pose) and its depth image (depth=on) until its landmarks
        come, the newest FRAMES_KEPT."""
        if self.params.depth == "on" and msg.depth is not None and not int(msg.halvings):
            self.depths[int(msg.stamp)] = DepthImage(msg.depth, msg.depth_K, msg.depth_to_color)
            while len(self.depths) > self.FRAMES_KEPT:
                self.depths.popitem(last=False)
        if self.params.refine == "off":
            return
        image = msg.image
        if int(msg.halvings) or not (isinstance(image, np.ndarray) and image.ndim == 3 and image.dtype == np.uint8):
            self.count("refine_bad_frame")
            return
        self.frames[int(msg.stamp)] = image
        while len(self.frames) > self.FRAMES_KEPT:
            self.frames.popitem(last=False)
        # the waiting landmarks' frame came, or a later one did (theirs was lost): fit them now
        if self.waiting is not None and int(msg.stamp) >= int(self.waiting.stamp):
            waiting, self.waiting = self.waiting, None
            self.handle_landmarks(waiting)

    def frame_for(self, msg: FaceLandmarks, size: tuple[int, int]) -> np.ndarray | None:
        """The camera frame of ``msg`` (W, H = ``size``) when refining and it arrived, else None
        (counted)."""
        if self.params.refine == "off":
            return None
        image = self.frames.get(int(msg.stamp))
        if image is None or image.shape[1::-1] != size:
            self.count("refine_without_frame")
            return None
        return image

    def depth_for(self, msg: FaceLandmarks) -> DepthImage | None:
        """The depth image of ``msg``'s frame (depth=on) when it came, else None (counted)."""
        if self.params.depth != "on":
            return None
        depth = self.depths.get(int(msg.stamp))
        if depth is None:
            self.count("depth_without_frame")
        return depth

    def fitter_config(self) -> FitterConfig:
        """The fitter's options from this node's params (the others at their defaults)."""
        p = self.params
        values = {name: getattr(p, name) for name in FITTER_PARAMS}
        return FitterConfig(**{**values, "refine": None if p.refine == "off" else p.refine})

    def prepare_fitter(self, size: tuple[int, int], K: np.ndarray | None) -> None:
        """A fitter for this camera (image size, K), made anew when the camera changed; the
        frame's K is ignored when the projection is orthographic. Raises FitError."""
        key = (size, None if K is None else K.round(6).tobytes())
        if self.faces is not None and key == self.camera_key:
            return
        if self.faces is not None:
            self.count("camera_changed")
        K = None if self.params.projection == "orthographic" else K
        config = self.fitter_config()
        FitCamera.make(size, K, config.projection)  # raises FitError now for a camera it cannot fit
        self.faces = FaceFitters(lambda: make_fitter(self.model, config, size, K), self.selection)
        self.camera_key = key

    def on_landmarks(self, msg: FaceLandmarks):
        """One face/state per landmarks message: the fit, or an empty state when there is none.
        With refine=appearance or pose a message whose frame has not come yet waits for it (one at a time:
        an older waiting one is fitted unrefined)."""
        if self.params.refine != "off" and int(msg.stamp) not in self.frames:
            if self.waiting is not None:
                self.handle_landmarks(self.waiting)
            self.waiting = msg
            return
        self.handle_landmarks(msg)

    def handle_landmarks(self, msg: FaceLandmarks):
        published = self.state_pub.count
        try:
            self.fit_frame(msg)
        finally:
            if self.state_pub.count == published:
                self.publish_no_face(msg)

    def publish_no_face(self, msg: FaceLandmarks) -> None:
        """An empty FaceState (0 vertices) for the frame of ``msg``: no fit on it."""
        try:
            size = [int(msg.image_size[0]), int(msg.image_size[1])]
        except (TypeError, ValueError, IndexError):
            size = [0, 0]
        self.state_pub.publish(FaceState(
            stamp=msg.stamp, frame_id=msg.frame_id, model_id=self.model.model_id if self.model else "",
            vertices=np.zeros((0, 3), np.float32), projected=np.zeros((0, 2), np.float32), image_size=size,
            faces=0,
        ))

    def fit_frame(self, msg: FaceLandmarks) -> None:
        """Stage 2 on one landmarks message; publishes the state when a face was fitted."""
        if self.model is None:
            self.count("no_model")
            return
        try:
            size = (int(msg.image_size[0]), int(msg.image_size[1]))
        except (TypeError, ValueError, IndexError):
            size = (0, 0)
        if size[0] <= 0 or size[1] <= 0:
            self.count("bad_image_size")
            return
        K = np.asarray(msg.K, np.float64) if valid_intrinsics(msg.K) else None
        if self.params.projection == "perspective" and K is None:
            self.count("bad_intrinsics")
            return
        try:
            self.prepare_fitter(size, K)
        except FitError as exc:
            self.count("fit_refused")
            self.last_error = str(exc)
            return
        # Each face's targets from its points in this frame (the head's pose, not a fit they pulled).
        targets = {k: partial(c.targets, self.last_fits[k]) for k, c in self.corrections.items()
                   if c and k in self.last_fits}
        image = self.frame_for(msg, size)
        with self.stage("fit"):
            faces = self.faces.fit(msg.points, msg.scores, msg.track_ids, msg.stamp * 1e-9, self.params.min_score,
                                   targets, image=image, depth=self.depth_for(msg))
        if not faces:
            self.count("no_face" if np.shape(msg.points)[0] == 0 else "face_not_selected")
        fitted = [f for f in faces if f.outcome.fit is not None]
        for f in faces:
            if f.outcome.fit is None:
                self.count(f.outcome.skipped)
                if f.outcome.error:
                    self.last_error = f.outcome.error
        expressions_wanted = bool(fitted) and self.expression_pub.subscriber_count() > 0
        for f in fitted:
            result = f.outcome.fit
            self.last_fits[f.key], self.last_points[f.key] = result, np.asarray(msg.points[f.index])
            dense = self.faces.fitters[f.key].model.dense
            corrected = self.corrections.get(f.key)
            self.state_pub.publish(FaceState(
                stamp=msg.stamp, frame_id=msg.frame_id, model_id=self.model.model_id,
                R=np.asarray(result.R, np.float64), t=np.asarray(result.t, np.float64), scale=float(result.scale),
                K=np.asarray(msg.K, np.float64) if np.shape(msg.K) == (3, 3) else np.eye(3),
                alpha=result.alpha.astype(np.float32), beta=result.beta.astype(np.float32),
                vertices=result.vertices, projected=result.projected, residual_px=float(result.residual_px),
                image_size=[size[0], size[1]], projection=result.projection, face_id=f.key, faces=len(fitted),
                landmarks=ibug68_points(result, dense), corrected=corrected.ibug(dense) if corrected else [],
            ))
            self.count("fitted")
            if not expressions_wanted:  # nobody listens: spare the frame path their cost
                continue
            fitter = self.faces.fitters[f.key]
            with self.stage("expression"):
                values = face_expression(result, fitter.model, fitter.neutral, msg.points[f.index])
            with self.stage("expression_label"):
                recogniser = self.recognisers.setdefault(f.key, ExpressionRecogniser(self.label_options))
                label = recogniser.update(msg.stamp * 1e-9, values, NAMES, result.beta,
                                          fitter.model.expression_names, result.yaw_pitch_roll[:2])
            self.expression_pub.publish(FaceExpression(
                stamp=msg.stamp, frame_id=msg.frame_id, face_id=f.key, pose=head_pose(result), names=list(NAMES),
                values=values, label=label.label, intensity=label.intensity, phase=label.phase,
                label_scores=label.scores))
        if fitted and msg.irises is not None and msg.eye_lids is not None:
            self.publish_gaze(msg, fitted)
        if fitted:
            self.maybe_publish_model(msg.stamp, msg.stamp * 1e-9)


def gaze_message(gaze: Gaze, stamp: int, frame_id: str, face_id: int) -> FaceGaze:
    """The ``face/gaze`` message of one face's :class:`~.gaze.Gaze`."""
    f4 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    return FaceGaze(stamp=stamp, frame_id=frame_id, face_id=int(face_id), centres=f4(gaze.centres),
                    directions=f4(gaze.directions), eye_angles=f4(gaze.eye_angles), confidences=f4(gaze.confidences),
                    closed=np.asarray(gaze.closed, np.uint8), openings=f4(gaze.openings), origin=f4(gaze.origin),
                    direction=f4(gaze.direction),
                    angles=f4([gaze.yaw_deg, gaze.pitch_deg, gaze.head_yaw_deg, gaze.head_pitch_deg]),
                    vergence_deg=float(gaze.vergence_deg), fixation=f4(gaze.fixation),
                    confidence=float(gaze.confidence), learned=bool(gaze.learned))
