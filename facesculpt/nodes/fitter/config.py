"""Every option of the fitters (:func:`.fitter.make_fitter`), with its unit and valid range.

The fitter node builds one from its parameters, the in-process pipeline from its options; the
defaults are the node's. An option out of range raises :class:`.result.FitError` (a ValueError)
with one sentence naming it.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, fields

from facesculpt.nodes.fitter.result import FitError

PROJECTIONS = ("auto", "perspective", "orthographic")
OUTLINE_MODES = ("ray", "nearest", "off")
COEFFICIENT_SOLVES = ("joint", "alternate")


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
    refine: None, or "appearance": after the landmark fit of a frame given with its ``image``, the
    pose is refined photometrically against the person's appearance learned from the earlier
    frames (:mod:`.appearance`, issue 20); ``refine_after`` (>= 1): frames learned first.
    """

    projection: str = "auto"
    iterations: int = 5
    tracking_iterations: int | None = 1
    shape_lambda: float = 3.0
    expression_lambda: float = 4.0
    outline: str = "ray"
    coefficients: str = "joint"
    inner_steps: int = 3
    outline_weight: float = 0.3
    num_shape: int | None = None
    min_landmarks: int = 6
    accumulate_identity: bool = True
    identity_decay: float = 0.98
    identity_max_frames: float = 50.0
    smoothing: bool = True
    smooth_min_cutoff: float = 1.5
    smooth_beta: float = 0.5
    smooth_beta_mm: float = 0.05
    smooth_beta_rotation: float | None = None
    smooth_predict_rotation: float = 0.0
    smooth_predict_mm: float = 0.0
    neutral_frames: int = 30
    warm_start_gap_s: float = 0.5
    correction_weight: float = 20.0
    rotation_prior_px: float = 100.0
    refine: str | None = None
    refine_after: int = 10

    def __post_init__(self) -> None:
        _choice("projection", self.projection, PROJECTIONS)
        _choice("outline", self.outline, OUTLINE_MODES)
        _choice("coefficients", self.coefficients, COEFFICIENT_SOLVES)
        if self.refine not in (None, "appearance"):
            raise FitError(f"refine must be None or 'appearance', got {self.refine!r}")
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
