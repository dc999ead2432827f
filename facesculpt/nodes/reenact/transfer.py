"""A fitted face's expression displacement from its own neutral, from what ``face/state`` carries.

The fitter's state gives the fitted mesh in camera space and the pose; :func:`model_space_shape`
takes the mesh back into model space (inverting the dense fitter's metric weak perspective
exactly, or the similarity of an orthographic or sparse fit), and :func:`expression_displacement`
subtracts the person's neutral: the displacement (V, 3) mm that, merged into another person's fit
(paper Eq. 5), makes that face move as this one does, relative to each one's own neutral.
"""

from __future__ import annotations

import numpy as np


def model_space_shape(vertices: np.ndarray, R: np.ndarray, t: np.ndarray, scale: float,
                      projection: str = "perspective") -> np.ndarray:
    """(V, 3) float64 model space (mm) of a fitted mesh ``vertices`` (V, 3) camera space.

    R (3, 3), t (3,), scale: the state's pose (``x_cam = scale * R @ x_model + t``). Under
    ``"perspective"`` with scale 1 (the dense fitter's metric weak perspective: each point's x, y
    scaled by its depth Z over the pose's depth t_z) that scaling is undone first; otherwise the
    similarity is inverted."""
    v = np.asarray(vertices, np.float64)
    Rm, tv = np.asarray(R, np.float64), np.asarray(t, np.float64)
    if projection == "perspective" and abs(float(scale) - 1.0) < 1e-9 and tv[2] > 0:
        z0 = tv[2]
        rotated = np.column_stack([v[:, 0] * z0 / v[:, 2] - tv[0], v[:, 1] * z0 / v[:, 2] - tv[1], v[:, 2] - z0])
        return rotated @ Rm
    return (v - tv) @ Rm / float(scale)


def expression_displacement(shape: np.ndarray, neutral: np.ndarray, gain: float = 1.0) -> np.ndarray:
    """(V, 3) float32 mm: ``gain`` times ``shape`` minus the same person's ``neutral`` (both (V, 3)
    model space, mm); ValueError when their shapes differ."""
    s, n = np.asarray(shape, np.float64), np.asarray(neutral, np.float64)
    if s.shape != n.shape or s.ndim != 2 or s.shape[1] != 3:
        raise ValueError(f"shape {s.shape} and neutral {n.shape} must both be (V, 3)")
    return (float(gain) * (s - n)).astype(np.float32)
