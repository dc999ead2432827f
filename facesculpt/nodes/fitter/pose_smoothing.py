"""Temporal smoothing of a fitted face: One Euro filters (:mod:`.smoothing`) on the head pose,
the expression and (dense) the fitted shape.

The rotation is filtered as a rotation vector relative to the frontal pose, the translation in
model millimetres (an orthographic t is in pixels: it is divided by the scale first, so the
filter's speed threshold means the same at any face size).
"""

from __future__ import annotations

import numpy as np

from facesculpt.nodes.fitter import pose
from facesculpt.nodes.fitter.smoothing import OneEuroFilter


class PoseSmoother:
    """min_cutoff Hz; beta Hz per unit/s for scale and expression; beta_rotation Hz per rad/s for
    the rotation (None: ``beta``); beta_mm Hz per mm/s for translation and vertices;
    predict_rotation (rad/s) and predict_mm (mm/s; 0: off): the rotation's and the translation's
    filters predict at constant velocity, weighed in as the speed clears them
    (:class:`.smoothing.OneEuroFilter`); orthographic: t is in pixels, s in px per mm."""

    def __init__(self, min_cutoff: float, beta: float, beta_mm: float, orthographic: bool,
                 beta_rotation: float | None = None, predict_rotation: float = 0.0, predict_mm: float = 0.0):
        self.orthographic = orthographic
        self._filters = {k: OneEuroFilter(min_cutoff, beta) for k in ("s", "beta")}
        self._filters["rot"] = OneEuroFilter(min_cutoff, beta if beta_rotation is None else beta_rotation,
                                             predict_speed=predict_rotation)
        self._filters["t"] = OneEuroFilter(min_cutoff, beta_mm, predict_speed=predict_mm)
        self._filters["shape"] = OneEuroFilter(min_cutoff, beta_mm)   # millimetre-valued signals

    def reset(self) -> None:
        """Forget the past: the next values pass through unfiltered."""
        for f in self._filters.values():
            f.reset()

    def rigid(self, R: np.ndarray, t: np.ndarray, s: float, now: float):
        """The smoothed head pose (R (3, 3), t (3,), s) at time ``now`` (s)."""
        rot = pose.rotation_log(R @ pose.FRONTAL.T)
        rot = self._filters["rot"](rot, now)
        unit = s if self.orthographic else 1.0
        s_new = float(self._filters["s"](np.array([s]), now)[0])
        t = self._filters["t"](t / unit, now) * (s_new if self.orthographic else 1.0)
        return pose.rodrigues(rot) @ pose.FRONTAL, t, s_new

    def hold_rigid(self, R: np.ndarray, t: np.ndarray, s: float) -> None:
        """Make (R, t, s) the last smoothed pose (a bound applied to it outside)."""
        self._filters["rot"].hold(pose.rotation_log(R @ pose.FRONTAL.T))
        self._filters["s"].hold(np.array([s]))
        self._filters["t"].hold(t / (s if self.orthographic else 1.0))

    def hold_shape(self, vertices: np.ndarray) -> None:
        """Make ``vertices`` (V, 3) mm the last smoothed shape."""
        self._filters["shape"].hold(vertices)

    def expression(self, beta: np.ndarray, now: float) -> np.ndarray:
        """The smoothed expression coefficients (E,) at time ``now`` (s)."""
        return self._filters["beta"](beta, now) if len(beta) else beta

    def shape(self, vertices: np.ndarray, now: float) -> np.ndarray:
        """The smoothed shape (V, 3), model space (mm), at time ``now`` (s)."""
        return self._filters["shape"](vertices, now)
