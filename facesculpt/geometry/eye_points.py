"""The eyes' points of the face mesh and of the iBUG-68 scheme, and how open an eye is.

Eye 0 is always the person's right eye (image left in an unmirrored frame), eye 1 the left. The
face mesh's lids are 16 points per eye, in the order MediaPipe's iris network gives its first 16
eye-contour points: the lower lid from the outer corner (0) to the inner corner (8), then the
upper lid from beside the outer corner (9) to beside the inner one (15). The landmarks room runs
the iris network on them; the fitter room places the eyeballs from them.
"""

from __future__ import annotations

import numpy as np

#: The face mesh's eye corners per eye: (outer, inner).
MESH_EYE_CORNERS = ((33, 133), (263, 362))
#: The face mesh's 16 lid points per eye (the order above).
MESH_EYE_LIDS = (
    (33, 7, 163, 144, 145, 153, 154, 155, 133, 246, 161, 160, 159, 158, 157, 173),
    (263, 249, 390, 373, 374, 380, 381, 382, 362, 466, 388, 387, 386, 385, 384, 398),
)
#: iBUG-68 numbers (1-based) of each eye's corners (outer, inner) and its six lid points.
IBUG_EYE_CORNERS = (("37", "40"), ("46", "43"))
IBUG_EYE_LIDS = (("37", "38", "39", "40", "41", "42"), ("43", "44", "45", "46", "47", "48"))
#: Pairs (lower, upper) of the 16 lid points facing each other across the eye's middle.
_FACING_PAIRS = ((3, 11), (4, 12), (5, 13))


def eye_opening(lids: np.ndarray) -> np.ndarray:
    """How open each eye is: (..., 16, >=2) lid points (pixels) -> (...) float64, the mean
    distance between the lower and upper lid across the eye's middle divided by the distance
    between its corners (0: shut; an open adult eye is about 0.25 to 0.4)."""
    lids = np.asarray(lids, np.float64)[..., :2]
    lower = lids[..., [p[0] for p in _FACING_PAIRS], :]
    upper = lids[..., [p[1] for p in _FACING_PAIRS], :]
    gap = np.linalg.norm(upper - lower, axis=-1).mean(axis=-1)
    width = np.linalg.norm(lids[..., 0, :] - lids[..., 8, :], axis=-1)
    return gap / np.maximum(width, 1e-9)
