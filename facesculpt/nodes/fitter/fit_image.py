"""A 3D active appearance model fit of one photo (seed 004): the landmark fit, aligned by appearance.

:func:`fit_image` starts from a photo's landmark fit and moves the head's pose (and, with
SHAPE_COMPONENTS, the shape model's leading components) so the photo, sampled at the projected
vertices, matches the appearance model (:mod:`.appearance_model`: the mean face plus its
components, mixed for this face, with the lighting's gain and bias) by the Gauss-Newton of
:func:`.appearance.refine_pose`, held near the landmarks by its prior. The model is trained on
frontal faces only; seed 004's claim is that turned faces then align too, since the texture lives
on the model's vertices.

Arrays in, arrays out: :meth:`.fitter.Fitter.fit_image` calls it with the fitter's model and camera.
"""

from __future__ import annotations

import cv2
import numpy as np

from facesculpt.geometry.vertex_normals import vertex_normals

from . import appearance
from .appearance_model import AppearanceModel
from .appearance_refiner import refined_result, shape_bases
from .model import MorphableModel
from .result import FitError, FitResult

#: refine_pose calls, each warm-started from the last (a photo has time for more steps than a frame).
ROUNDS = 3
#: The landmark prior (appearance.PRIOR_WEIGHT's meaning): an appearance model learned from a few
#: dozen faces knows less than the landmarks; held weaker, the fit wanders (bench_fit_image.py).
PRIOR_WEIGHT = 100.0
#: Shape components aligned with the pose (0: the pose only; the shape components made the 68
#: points worse on the shared photos).
SHAPE_COMPONENTS = 0


def fit_image(image: np.ndarray, init: FitResult, model: MorphableModel, appearance_model: AppearanceModel,
              K: np.ndarray | None, projection: str, prior_weight: float | None = None) -> FitResult:
    """``init`` (the landmark fit of ``image`` with ``model``) aligned by appearance.

    image: (H, W, 3) uint8 BGR or (H, W) grey; K: (3, 3) intrinsics, or None for orthographic
    (then ``projection`` "orthographic"); prior_weight: the landmark prior (default
    PRIOR_WEIGHT). Raises :class:`.result.FitError` when the appearance model was made for
    another face model."""
    if len(appearance_model.mean) != len(init.vertices):
        raise FitError(f"the appearance model has {len(appearance_model.mean)} vertices, the fit "
                       f"{len(init.vertices)}: it was trained for another face model ({appearance_model.model_id!r})")
    prior_weight = PRIOR_WEIGHT if prior_weight is None else prior_weight
    grey = np.asarray(image, np.float32) if image.ndim == 2 else \
        cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2GRAY).astype(np.float32)
    X = np.asarray(init.vertices, np.float64)
    weights = appearance.frontal_weights(appearance.frontality(X, vertex_normals(X, model.triangles), K is not None))
    k = min(SHAPE_COMPONENTS, len(init.alpha), model.num_shape)
    model_basis, basis = shape_bases(model, init, k)
    anchors = np.asarray(model.landmark_vertices, np.int64)
    template = appearance_model.basis()
    found = None
    for _ in range(ROUNDS):
        found = appearance.refine_pose(grey, X, weights, template, K, anchors, prior_weight=prior_weight,
                                       basis=basis, start=None if found is None else found.theta,
                                       temporal_weight=0.0)
    return refined_result(init, found, model_basis, K, projection)
