"""Morphable-model fitting: pose, shape, expression, outline correspondences (docs/architecture.md,
"Stages": stage 2).

``load_model("facemesh" | "sfm" | path.npz)`` gives a :class:`MorphableModel`;
``make_fitter(model, FitterConfig(...), image_size=(W, H), K=None)`` gives the fitter for it
(sparse or dense), which fits 2D landmarks frame by frame and returns a :class:`FitResult`;
:func:`fit_landmarks` is the stage itself on one landmarks message.
``import_eos(shape_bin, blendshapes=..., landmarks=..., contours=...)`` builds a model from eos
files in memory.

Files, one concept each: ``model.py`` (the model format, .npz save/load), ``eos_import.py``,
``eos_reader.py``, ``facemesh_model.py`` (the built-in model); ``config.py`` (the options),
``model_loading.py`` (:func:`load_model`), ``fitter.py`` (what both fitters share), ``fitter_factory.py`` (:func:`make_fitter`), ``sparse_fitter.py``,
``dense_fitter.py``, ``result.py``, ``fit_camera.py``, ``pose.py``, ``fitting.py`` (the
coefficient solves), ``outline.py``, ``pose_smoothing.py`` and ``smoothing.py`` (One Euro),
``neutral_learning.py``; ``stage.py`` (the stage, :func:`fit_landmarks`); ``faces.py`` (several faces:
the selection and one fitter per face, :class:`FaceFitters`); ``node.py`` (the node shell).
"""

from facesculpt.nodes.fitter.eos_import import import_eos
from facesculpt.nodes.fitter.facemesh_model import facemesh_model
from facesculpt.nodes.fitter.model import ModelFormatError, MorphableModel, save_model
from facesculpt.nodes.fitter.model_loading import load_model

__all__ = [
    "FitError",
    "FitResult",
    "Fitter",
    "FaceFit",
    "FaceFitters",
    "FitterConfig",
    "LandmarksFit",
    "ModelFormatError",
    "MorphableModel",
    "facemesh_model",
    "fit_landmarks",
    "import_eos",
    "load_model",
    "make_fitter",
    "max_faces_for",
    "parse_faces",
    "save_model",
]

# The fitters pull in scipy; load them only when asked for.
_LAZY = {
    "Fitter": "fitter", "make_fitter": "fitter_factory", "FitResult": "result", "FitError": "result",
    "FitterConfig": "config", "fit_landmarks": "stage", "LandmarksFit": "stage",
    "FaceFitters": "faces", "FaceFit": "faces", "parse_faces": "faces", "max_faces_for": "faces",
}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
