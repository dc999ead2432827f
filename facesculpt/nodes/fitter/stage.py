"""Stage 2 on one landmarks message (docs/architecture.md, "Stages"): the fitter node and the
in-process pipeline (:mod:`facesculpt.app.pipeline`) both call :func:`fit_landmarks`.

It chooses the face to fit (the highest-scoring one, if that scores at least ``min_score``),
gives a sparse model the iBUG-68 points of the 468 face-mesh points
(:func:`facesculpt.geometry.to_ibug68`, ids "1".."68", with the network's relative depth) and a
dense one the 468 points as they are, and fits them. A frame that is not fitted says why, never raises.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesculpt.geometry import to_ibug68
from facesculpt.nodes.fitter.fitter import Fitter
from facesculpt.nodes.fitter.result import FitError, FitResult
from facesculpt.options import option

#: iBUG-68 landmark ids of a sparse model, in :func:`to_ibug68`'s order.
IBUG68_IDS = [str(i) for i in range(1, 69)]


@dataclass(frozen=True)
class StageOptions:
    """Which found faces the stage fits (the fitter node's and the pipeline's)."""

    min_score: float = option(0.5, "faces below this landmark score are not fitted", range=(0.0, 1.0))


#: The least landmark score of a face that is fitted (:class:`StageOptions`).
MIN_SCORE = StageOptions.min_score


@dataclass
class LandmarksFit:
    """The outcome of :func:`fit_landmarks`: ``fit`` the frame's :class:`FitResult`, or None
    with ``skipped`` saying why: "no_face", "low_score", "bad_landmark_count" or "fit_refused"
    (then ``error`` is the :class:`FitError`'s message)."""

    fit: FitResult | None
    skipped: str = ""
    error: str = ""


def fit_landmarks(fitter: Fitter, points, scores, stamp_s: float, min_score: float = MIN_SCORE,
                  corrections: dict | None = None, image: np.ndarray | None = None, depth=None) -> LandmarksFit:
    """Fit one frame's landmarks. points (F, N, 2 or 3) px: N = 468 face-mesh points per face
    (a sparse model also takes N = 68 iBUG points); scores (F,) face presence in [0, 1] (when
    their number is not F, the first face is taken); stamp_s: the frame time (s); corrections:
    fit id -> (x, y) px placed by hand (:mod:`.corrections`); image: the frame (H, W, 3) uint8, for
    a fitter that refines by appearance; depth: the frame's aligned depth image
    (:class:`.depth_fitting.DepthImage`), the fit then refined on it."""
    points = np.asarray(points)
    if points.ndim != 3 or points.shape[0] == 0:
        return LandmarksFit(None, "no_face")
    best = 0
    if len(scores) == points.shape[0]:
        best = int(np.argmax(scores))
        if float(scores[best]) < min_score:
            return LandmarksFit(None, "low_score")
    pts = points[best].astype(np.float64)
    ids = None
    if not fitter.model.dense:
        if pts.shape[0] == 468:
            pts = to_ibug68(pts, depth=True)  # the depth feeds the pose prior
        if pts.shape[0] != 68:
            return LandmarksFit(None, "bad_landmark_count")
        ids = IBUG68_IDS
    try:
        return LandmarksFit(fitter.fit(pts, ids, stamp=stamp_s, corrections=corrections, image=image,
                                       depth=depth))
    except FitError as exc:
        return LandmarksFit(None, "fit_refused", str(exc))
