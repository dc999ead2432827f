"""The neutral reference of one person, learned from the first frames of a dense fit.

Each frame's fitted shape is brought into model space (:func:`.facemesh_model.normalise_facemesh_neutral`:
centred, eye-corner axis, 90 mm), aligned by a similarity to the current reference, and
averaged; after ``frames`` frames the reference is frozen.
"""

from __future__ import annotations

import numpy as np

from facesculpt.nodes.fitter import pose
from facesculpt.nodes.fitter.facemesh_model import normalise_facemesh_neutral
from facesculpt.nodes.fitter.model import MorphableModel


class NeutralLearner:
    """Running mean, in model space, of the shapes of the first ``frames`` frames."""

    def __init__(self, frames: int):
        self.frames = int(frames)
        self.reset()

    def reset(self) -> None:
        self._sum: np.ndarray | None = None
        self.count = 0
        self.frozen = False

    def add(self, model: MorphableModel, observed: np.ndarray, similarity=None) -> MorphableModel | None:
        """Average one frame's shape into ``model``'s mean. observed (V, 3): the frame's points in
        pixel space; similarity (s, R, t): the pose that maps the model into it (None: the
        observation is taken as it is). Returns the model with the new mean, or None when the
        reference is frozen or the shape is degenerate."""
        if self.frozen:
            return None
        try:
            shape = normalise_facemesh_neutral(
                observed if similarity is None else (observed - similarity[2]) @ similarity[1] / similarity[0])
        except ValueError:
            return None
        if self.count:
            s2, R2, t2 = pose.similarity_procrustes(shape, model.mean)
            shape = s2 * shape @ R2.T + t2
        if self._sum is None:
            self._sum = np.zeros_like(shape, np.float64)
        self._sum += shape
        self.count += 1
        mean = normalise_facemesh_neutral(self._sum / self.count)
        base = model.source.split("; neutral learned")[0]
        if self.count >= self.frames:
            self.frozen = True
        return model.with_mean(mean, source=f"{base}; neutral learned from {self.count} frames")
