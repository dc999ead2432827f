"""Morphable-model fitting: pose, shape, expression, outline correspondences (DESIGN.md stage 2).

``load_model("facemesh" | "sfm" | path.npz)`` gives a :class:`MorphableModel`; ``Fitter(model,
image_size=(W, H), K=None)`` fits it to 2D landmarks frame by frame and returns a :class:`FitResult`.
``import_eos(shape_bin, blendshapes=..., landmarks=..., contours=...)`` builds a model from eos files
in memory; ``sfm_from_shared()`` does so from the shared Surrey Face Model folder.
"""

from facesculpt.nodes.fitter.model import (
    ModelFormatError,
    MorphableModel,
    facemesh_model,
    import_eos,
    load_model,
    save_model,
    sfm_from_shared,
)

__all__ = [
    "FitError",
    "FitResult",
    "Fitter",
    "ModelFormatError",
    "MorphableModel",
    "facemesh_model",
    "import_eos",
    "load_model",
    "save_model",
    "sfm_from_shared",
]


def __getattr__(name):
    # The fitter pulls in scipy; load it only when asked for.
    if name in ("Fitter", "FitResult", "FitError"):
        from facesculpt.nodes.fitter import fitter

        return getattr(fitter, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
