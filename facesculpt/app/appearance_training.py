"""Training the appearance model of :func:`facesculpt.nodes.fitter.fit_image.fit_image` (seed 004)
from photos: each face the landmark networks find is fitted by its landmarks (SFM or any sparse
68-landmark model, perspective with a 53° field of view), and the frontal ones (|yaw| up to
``max_yaw_deg``) are sampled at the model's vertices
(:func:`~facesculpt.nodes.fitter.appearance_model.vertex_appearance`) and reduced to their mean
and leading components. ``facesculpt model train-appearance`` runs it.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

#: Faces turned further than this (degrees, either way) are not learned from: seed 004 trains on
#: frontal faces only.
MAX_YAW_DEG = 15.0
#: Components kept.
COMPONENTS = 10


def photo_fits(image: np.ndarray, model, detector) -> list:
    """The landmark fit (FitResult) of every face the ``detector`` (a LandmarkDetector) finds in
    ``image`` (H, W, 3) uint8 BGR, each by a fresh fitter of ``model`` (a sparse MorphableModel)."""
    from facesculpt.geometry import to_ibug68
    from facesculpt.nodes.fitter import FitError, FitterConfig, make_fitter
    from facesculpt.nodes.fitter.stage import IBUG68_IDS

    h, w = image.shape[:2]
    K = np.array([[w, 0, w / 2], [0, w, h / 2], [0, 0, 1.0]])
    fits = []
    for face in detector.detect(image):
        try:
            fits.append(make_fitter(model, FitterConfig(), (w, h), K).fit(to_ibug68(face.points).astype(np.float64),
                                                                        IBUG68_IDS))
        except FitError:
            continue
    return fits


def frontal_samples(image: np.ndarray, fits: list, model, max_yaw_deg: float = MAX_YAW_DEG) -> list[np.ndarray]:
    """(V,) normalised vertex grey levels of each of ``fits`` (of ``image``) turned by at most
    ``max_yaw_deg``."""
    from facesculpt.nodes.fitter.appearance_model import vertex_appearance

    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float32)
    return [vertex_appearance(grey, np.asarray(f.vertices, np.float64), np.asarray(f.projected, np.float64),
                              model.triangles, True)
            for f in fits if abs(f.yaw_pitch_roll[0]) <= max_yaw_deg]


def train_from_photos(paths: list[Path], model_name: str = "sfm", components: int = COMPONENTS,
                      max_yaw_deg: float = MAX_YAW_DEG, min_face: float = 0.05):
    """(AppearanceModel, faces learned from) over the photos ``paths``; ValueError when fewer
    than 2 frontal faces were found."""
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.fitter.appearance_model import train_appearance
    from facesculpt.nodes.landmarks import LandmarkDetector

    model = load_model(model_name)
    if model.dense:
        raise ValueError(f"the appearance model is for a sparse model with a shape basis (sfm), not {model_name!r}")
    detector = LandmarkDetector(max_faces=50, min_face=min_face)
    samples = []
    for path in paths:
        image = cv2.imread(str(path))
        if image is None:
            continue
        samples += frontal_samples(image, photo_fits(image, model, detector), model, max_yaw_deg)
    if len(samples) < 2:
        raise ValueError(f"only {len(samples)} frontal face(s) in {len(paths)} photo(s): at least 2 are needed")
    return train_appearance(np.array(samples), components, model.model_id), len(samples)
