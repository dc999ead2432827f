"""The fitter for a model: :class:`.dense_fitter.DenseFitter` for a dense model (the face mesh),
:class:`.sparse_fitter.SparseFitter` otherwise. Apart from :mod:`.fitter` (what both share), which
both subclass."""

from __future__ import annotations

import numpy as np

from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.nodes.fitter.fit_camera import FitCamera
from facesculpt.nodes.fitter.fitter import Fitter
from facesculpt.nodes.fitter.model import MorphableModel
from facesculpt.nodes.fitter.model_loading import load_model


def make_fitter(model: MorphableModel | str = "facemesh", config: FitterConfig | None = None,
                image_size=(640, 480), K: np.ndarray | None = None) -> Fitter:
    """The fitter for ``model`` (a :class:`MorphableModel`, or a name or path for
    :func:`.model.load_model`): dense when ``model.dense``, sparse otherwise. config: the options
    (default :class:`FitterConfig`'s); image_size (W, H) px; K (3, 3) intrinsics or None.
    Raises :class:`FitError` for a bad image size, K or projection."""
    # only the fitter used is imported: the sparse one brings scipy, which would lengthen a
    # respawned dense fitter's start-up
    model = model if isinstance(model, MorphableModel) else load_model(model)
    config = FitterConfig() if config is None else config
    camera = FitCamera.make(image_size, K, config.projection)
    if model.dense:
        from facesculpt.nodes.fitter.dense_fitter import DenseFitter

        return DenseFitter(model, config, camera)
    from facesculpt.nodes.fitter.sparse_fitter import SparseFitter

    return SparseFitter(model, config, camera)
