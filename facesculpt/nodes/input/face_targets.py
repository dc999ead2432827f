"""Where on the fitted face an input acts: the centre of the face's ROI, the landmark nearest a
pixel, and :class:`InputError` when an input cannot be turned into events. Pure functions:
pixels (V, 2) float in, names and pixels out."""

from __future__ import annotations

import numpy as np


class InputError(ValueError):
    """An input that cannot be turned into events (no face to grab, unknown landmark, ...)."""


def roi_centre(projected: np.ndarray) -> np.ndarray:
    """Centre (2,) pixels of the bounding box of the projected fitted face ``projected`` (V, 2)."""
    p = np.asarray(projected, np.float64)
    p = p[np.all(np.isfinite(p), axis=1)]
    if p.size == 0:
        raise InputError("the fitted face has no projected vertices")
    return (p.min(axis=0) + p.max(axis=0)) / 2.0


def nearest_landmark(projected: np.ndarray, names: list[str], vertices: np.ndarray, point) -> str:
    """The landmark whose projection (pixels, from ``projected`` (V, 2)) is nearest ``point`` (x, y).

    ``names[i]`` is the landmark at vertex ``vertices[i]``. Among names of one vertex (an iBUG
    number and a semantic name) the semantic one wins."""
    idx = np.asarray(vertices, np.int64)
    if len(names) == 0 or idx.size != len(names):
        raise InputError("the face model has no landmark names")
    ok = (idx >= 0) & (idx < len(projected))
    if not np.any(ok):
        raise InputError("the face model's landmark vertices are not in the fitted face")
    d = np.linalg.norm(np.asarray(projected, np.float64)[np.where(ok, idx, 0)] - np.asarray(point, np.float64), axis=1)
    d = np.where(ok & np.isfinite(d), d, np.inf)
    best = min(range(len(names)), key=lambda i: (round(float(d[i]), 6), names[i].isdigit(), i))
    return names[best]

