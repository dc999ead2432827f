"""The project's compositor given the scene's true geometry: how far the rendering alone, and the
rendering with the deformer's own version of the edit, are from the ground truth, with no fit.

``process`` loses to the truth in three places: the renderer (sampling, fill, feathering), the
deformer (the preset solved by ARAP is not the benchmark's raised-cosine falloff) and the fit
(pose and shape from the landmarks). These rows take the fit away: the true head's camera-space
vertices and their true projection stand in for the fitted ones, so the gap between them and a
model's row is what registration costs.
"""

from __future__ import annotations

import numpy as np

from .edits import EditSpec, preset
from .raster import project_pixels
from .scene import Scene


def deformer_displacement(spec: EditSpec, scene: Scene, **options) -> np.ndarray:
    """(V, 3) mm: the edit as the project's deformer solves its preset on the true head's rest mesh
    (the model's vertices; the vertices that close the mouth keep the benchmark's own falloff);
    ``options`` go to the deformer's ``EditStack`` (e.g. ``grip=0.2``; default: its defaults)."""
    from facesculpt.nodes.deformer import EditStack

    from .edits import displacement

    n = scene.model_vertices
    rest = scene.rest[:n]
    stack = EditStack(rest.astype(np.float32), scene.model_triangles, list(scene.landmarks),
                      list(scene.landmarks.values()), **options)
    stack.apply_preset(preset(spec, rest, scene.landmarks, scene.model_triangles))
    out = displacement(spec, scene.rest, scene.landmarks)
    out[:n] = stack.settle()
    return out


def oracle_frames(scene: Scene, inputs: list, displacement: np.ndarray, frames: list[int]) -> list:
    """The compositor's output (the defaults ``process`` uses) for each of ``frames`` (indices into
    ``inputs``, the unedited renders), drawing the true head moved by ``displacement`` (V, 3) mm,
    model space; None for the other indices. Frames are composited in order, as a video is."""
    from facesculpt.nodes.renderer import Compositor

    n = scene.model_vertices
    height, width = inputs[0].shape[:2]
    out: list = [None] * len(inputs)
    compositor = Compositor(width, height)
    try:
        for i in frames:
            X0 = scene.to_camera(scene.rest, i)[:n]
            X1 = scene.to_camera(scene.rest + displacement, i)[:n]
            out[i] = compositor.render(inputs[i], X0, project_pixels(scene.K, X0), scene.model_triangles, X1)
    finally:
        compositor.release()
    return out
