"""Every option of the fitters (:func:`.fitter_factory.make_fitter`), declared once with its
default, unit, valid range and help (:func:`facesculpt.options.option`).

The fitter node's parameters derive from these fields, and the in-process pipeline takes a
:class:`FitterConfig` itself. An option out of range raises :class:`.result.FitError` (a ValueError)
with one sentence naming it.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, fields

from facesculpt.nodes.fitter.result import FitError
from facesculpt.options import check_options, option

PROJECTIONS = ("auto", "perspective", "orthographic")
OUTLINE_MODES = ("ray", "nearest", "off")
COEFFICIENT_SOLVES = ("joint", "alternate")
REFINE_MODES = ("appearance", "pose")


@dataclass(frozen=True)
class FitterConfig:
    """How a fitter fits; the camera (image size, intrinsics K) is given separately.

    projection: "perspective" (needs K), "orthographic", or "auto" (perspective when K is given).
    iterations (>= 1): pose / outline-correspondence / coefficient iterations of a cold-started
    frame (sparse). tracking_iterations (>= 1, or None: always ``iterations``; at most
    ``iterations``): iterations of a frame warm-started from the previous one, whose pose, shape
    and expression are already close.
    shape_lambda, expression_lambda (>= 0, mm²): λ of paper Eq. 2 (:mod:`.fitting`).
    outline: the outline landmarks' correspondences: "ray" (the paper's ray-triangle points),
    "nearest" (nearest outline vertex) or "off" (outline landmarks ignored).
    coefficients: "joint" (per iteration, the fixed point of the beta-given-alpha /
    alpha-given-beta alternation, solved exactly, :func:`.fitting.solve_joint`) or "alternate"
    (one beta then one alpha solve per iteration, as eos does).
    inner_steps (>= 1): pose / coefficient alternations per iteration (the outline
    correspondences are updated once per iteration).
    outline_weight (> 0): weight of an outline landmark relative to a fixed one (they slide
    along the silhouette and are annotated less precisely).
    num_shape (>= 0, or None: all): leading shape components fitted (at most the model's).
    min_landmarks (>= 4): fewest landmarks with a fixed model vertex a frame needs (dense: at
    least half the mesh points are needed as well).
    accumulate_identity: keep identity (shape) evidence across frames (sparse);
    identity_decay (0 < d <= 1): the weight an earlier frame's evidence keeps per frame;
    identity_max_frames (> 0): cap on the evidence's total weight, in frames.
    smoothing: One Euro filtering of the pose, the expression and (dense) the fitted shape;
    smooth_min_cutoff (> 0, Hz); smooth_beta (>= 0, Hz per unit/s) for rotation (rad), scale
    and expression; smooth_beta_mm (>= 0, Hz per mm/s) for translation and dense vertices;
    smooth_beta_rotation (>= 0, Hz per rad/s, or None: ``smooth_beta``) for the rotation alone;
    smooth_predict_rotation (>= 0, rad/s) and smooth_predict_mm (>= 0, mm/s; 0: off): the
    rotation's and the translation's filters predict at constant velocity, weighed in as their
    speed clears this (a still head keeps the plain filter).
    smooth_max_lag (0-1, share of the face's size; 0: off), dense: the smoothed fit's pixels keep
    within this mean distance of the frame's own points (the smoothed pose and shape are drawn
    toward the frame's, and the filters go on from there): smoothing takes out the points'
    jitter, never a motion larger than it (a fit that lags draws an edit beside the feature).
    neutral_frames (>= 1): frames averaged into the learned neutral reference (dense) and into
    the reference of the network's 3D points (sparse, ``rotation_prior_px``).
    warm_start_gap_s (> 0, s): a frame later than this after the previous one (or earlier than
    it) starts cold: no warm start, filters reset.
    correction_weight (> 0): weight of a user-corrected landmark relative to a detected one
    (``Fitter.fit(..., corrections=...)``).
    rotation_prior_px (>= 0, px per radian; 0: off): a sparse perspective fit given points with
    the network's relative depth ((N, 3)) holds its pitch toward that of the network's own 3D
    points (:mod:`.detector_rotation`) with this weight against the landmarks' RMS pixel error;
    the network's 3D reference is learned over ``neutral_frames`` frames.
    rotation_prior_settle_frames (>= 0, frames): the first frames' offsets are not learned.
    rotation_prior_relearn_frames (>= 0, frames; 0: off): with ``accumulate_identity``, what the
    first frames' landmark-only rotations were fitted from is kept (at most this many frames) and,
    once the identity has settled (its landmark points moved at most ``rotation_prior_relearn_mm``
    (>= 0, mm) over the last frame, after ``neutral_frames``; or the cap is reached), those
    rotations are fitted again with it, once, and the offset rebuilt from them.
    refine: None, "appearance" or "pose": after the landmark fit of a frame given with its ``image``,
    the pose is refined photometrically against the person's appearance learned from the earlier
    frames (:mod:`.appearance`, issue 20): "appearance" the pose and leading shape components from
    the whole face, "pose" the rigid pose alone from the forehead, nose bridge and cheekbones
    (:mod:`.rigid_regions`, issue 46) with a lighting gain and bias per region;
    ``refine_after`` (>= 1): frames learned first.
    """

    projection: str = option("auto", "perspective (needs K), orthographic, or auto: perspective when K is given",
                             choices=PROJECTIONS)
    iterations: int = option(5, "pose / outline-correspondence / coefficient iterations of a cold-started frame",
                             range=(1, 50))
    tracking_iterations: int | None = option(1, "iterations of a frame warm-started from the previous one (at "
                                                "most iterations)", range=(1, 50), none="always iterations")
    shape_lambda: float = option(3.0, "Eq. 2 regularisation of the shape coefficients", "mm²", range=(0.0, None))
    expression_lambda: float = option(4.0, "Eq. 2 regularisation of the expression coefficients", "mm²",
                                      range=(0.0, None))
    outline: str = option("ray", "contour correspondences: ray (the paper's ray-triangle points), nearest (nearest "
                                 "outline vertex), or off", choices=OUTLINE_MODES)
    coefficients: str = option("joint", "coefficient solve per iteration: joint (the alternation's fixed point, "
                                        "exact) or alternate (one shape then one expression solve, as eos)",
                               choices=COEFFICIENT_SOLVES)
    inner_steps: int = option(3, "pose / coefficient alternations per iteration", range=(1, 100))
    outline_weight: float = option(0.3, "weight of an outline landmark relative to a fixed one", range=(1e-9, None))
    num_shape: int | None = option(None, "leading shape components fitted (at most the model's)", range=(0, None),
                                   none="all")
    min_landmarks: int = option(6, "fewest landmarks with a fixed model vertex a frame needs", range=(4, None))
    accumulate_identity: bool = option(True, "keep identity (shape) evidence across frames (sparse)")
    identity_decay: float = option(0.98, "weight an earlier frame's identity evidence keeps per frame",
                                   range=(1e-9, 1.0))
    identity_max_frames: float = option(50.0, "cap on the identity evidence's total weight", "frames",
                                        range=(1e-9, None))
    smoothing: bool = option(True, "One Euro filtering of the pose, the expression and (dense) the fitted shape")
    smooth_min_cutoff: float = option(1.5, "One Euro minimum cutoff frequency", "Hz", range=(0.001, 100.0))
    smooth_beta: float = option(0.5, "One Euro speed coefficient of rotation, scale and expression",
                                "Hz per unit/s", range=(0.0, None))
    smooth_beta_mm: float = option(0.05, "One Euro speed coefficient of translation and dense vertices",
                                   "Hz per mm/s", range=(0.0, None))
    smooth_beta_rotation: float | None = option(None, "One Euro speed coefficient of the rotation alone",
                                                "Hz per rad/s", range=(0.0, None), none="smooth_beta")
    smooth_predict_rotation: float = option(0.0, "the rotation's filter predicts at constant velocity, weighed in "
                                                 "as its speed clears this (0: off)", "rad/s", range=(0.0, None))
    smooth_predict_mm: float = option(0.0, "the translation's filter predicts at constant velocity, weighed in as "
                                           "its speed clears this (0: off)", "mm/s", range=(0.0, None))
    smooth_max_lag: float = option(0.005, "dense: the smoothed fit keeps within this share of the face's size of "
                                         "the frame's own points (the mean over the vertices' pixels); a faster "
                                         "motion is followed, not lagged behind (0: no bound)",
                                   "share of the face's size", range=(0.0, 1.0))
    neutral_frames: int = option(30, "frames averaged into the learned neutral (dense) and into the landmark "
                                     "network's 3D reference (sparse, rotation_prior_px)", "frames",
                                 range=(1, 100000))
    warm_start_gap_s: float = option(0.5, "a frame later than this after the previous one starts cold", "s",
                                     range=(1e-9, None))
    correction_weight: float = option(20.0, "weight of a user-corrected landmark relative to a detected one",
                                      range=(1e-9, None))
    rotation_prior_px: float = option(100.0, "sparse, perspective: weight holding the fitted pitch toward that of "
                                             "the landmark network's own 3D points; 0: off", "px per radian",
                                      range=(0.0, 10000.0))
    rotation_prior_settle_frames: int = option(0, "sparse: the first frames, fitted before the person's identity is "
                                                  "learned, are left out of the offset between the network's head "
                                                  "frame and the model's (rotation_prior_px)", "frames",
                                               range=(0, 100000))
    rotation_prior_relearn_frames: int = option(150, "sparse, accumulating the identity: the first frames' "
                                                   "landmark-only rotations are kept (at most this many) and, once "
                                                   "the identity has settled (rotation_prior_relearn_mm), fitted "
                                                   "again with it and the offset of rotation_prior_px rebuilt from "
                                                   "them; 0: off", "frames", range=(0, 100000))
    rotation_prior_relearn_mm: float = option(0.05, "the identity has settled when its landmark points move less "
                                                    "than this over one frame (rotation_prior_relearn_frames)", "mm",
                                              range=(0.0, None))
    refine: str | None = option(None, "refine each landmark fit on its frame's pixels against the person's learned "
                                      "appearance and corners tracked from the last frame: appearance (pose and "
                                      "shape, whole face) or pose (rigid pose, rigid regions only; "
                                      "docs/guide/face-models.md)", choices=REFINE_MODES, none="landmarks only")
    refine_after: int = option(10, "frames learned before refine starts", "frames", range=(1, None))

    def __post_init__(self) -> None:
        _choice("projection", self.projection, PROJECTIONS)
        _choice("outline", self.outline, OUTLINE_MODES)
        _choice("coefficients", self.coefficients, COEFFICIENT_SOLVES)
        if self.refine is not None:
            _choice("refine", self.refine, REFINE_MODES)
        _at_least("refine_after", self.refine_after, 1)
        for name in ("iterations", "inner_steps", "neutral_frames"):
            _at_least(name, getattr(self, name), 1)
        _at_least("min_landmarks", self.min_landmarks, 4)
        if self.tracking_iterations is not None:
            _at_least("tracking_iterations", self.tracking_iterations, 1, "(or None)")
        if self.smooth_beta_rotation is not None and not self.smooth_beta_rotation >= 0:
            raise FitError(f"smooth_beta_rotation must be >= 0 (or None), got {self.smooth_beta_rotation}")
        if self.num_shape is not None:
            _at_least("num_shape", self.num_shape, 0, "(or None)")
        for name in ("shape_lambda", "expression_lambda", "smooth_beta", "smooth_beta_mm", "rotation_prior_px",
                     "smooth_predict_rotation", "smooth_predict_mm"):
            if not getattr(self, name) >= 0:
                raise FitError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("outline_weight", "identity_max_frames", "smooth_min_cutoff", "warm_start_gap_s",
                     "correction_weight"):
            if not getattr(self, name) > 0:
                raise FitError(f"{name} must be > 0, got {getattr(self, name)}")
        if not 0 < self.identity_decay <= 1:
            raise FitError(f"identity_decay must be in (0, 1], got {self.identity_decay}")
        check_options(self, FitError)  # the rest of each field's declared range and choices
        # Plain Python numbers from here on (numpy scalars and ints given for floats alike).
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type in ("int", "int | None") and value is not None:
                object.__setattr__(self, f.name, int(value))
            elif f.type in ("float", "float | None") and value is not None:
                object.__setattr__(self, f.name, float(value))


def _choice(name: str, value, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise FitError(f"{name} must be one of {', '.join(repr(c) for c in choices)}, got {value!r}")


def _at_least(name: str, value, lowest: int, alternative: str = "") -> None:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < lowest:
        raise FitError(f"{name} must be an integer >= {lowest}{' ' + alternative if alternative else ''}, got {value!r}")
