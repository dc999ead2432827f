"""A fixed mapping from the 468 face-mesh points to the iBUG-68 landmark scheme.

iBUG-68 (the 300-W scheme, 0-based here; the literature's 1-based numbers are one higher):

    0-16   jaw line, from the person's right ear (image left) over the chin (8) to the left ear
    17-21  right eyebrow, outer to inner      22-26  left eyebrow, inner to outer
    27-30  nose bridge, top to tip            31-35  nose base, image left to right (33 centre)
    36-41  right eye, from the outer corner (36) clockwise on screen: 37, 38 upper lid, 39 inner
           corner, 40, 41 lower lid
    42-47  left eye, from the inner corner (42): 43, 44 upper lid, 45 outer corner, 46, 47 lower
    48-59  outer lips, from the right mouth corner (48) over the upper lip (51 centre) to the
           left corner (54) and back along the lower lip (57 centre)
    60-67  inner lips, right corner (60), upper (62 centre), left corner (64), lower (66 centre)

How the mesh points were chosen: each iBUG point started from the mesh vertex at the same
anatomical place (eye corners 33/133/362/263, mouth corners 61/291, nose tip 4, chin 152,
face oval for the jaw, brow ridges, lid and lip contours), then moved to the vertex within one
mesh edge of it (or of its mirror partner's mirror image) that minimised the mean
inter-ocular-normalised error on the *training* half of the annotated faces in the shared
data (dlib's ``training_with_face_landmarks.xml``, 18 faces), with left-right pairs kept
mirror images of each other (the mesh's left-right symmetry, found from its triangles). The
testing half (25 faces) was held out; tests/test_landmarks_accuracy.py measures the error there.

The jaw is the weakest part: iBUG's jaw follows the visible silhouette, which moves over the
face as the head turns, while these are fixed mesh vertices (a fitter that needs the true
silhouette should search the mesh outline, as the paper's outline correspondence does).
"""

from __future__ import annotations

import numpy as np

NUM_MESH_POINTS = 468

# IBUG68_FROM_MESH[k] = mesh point for iBUG point k (0-based).
IBUG68_FROM_MESH = np.array([
    # jaw 0-16 (image left -> chin -> image right)
    127, 227, 132, 215, 172, 136, 149, 148, 152, 377, 378, 365, 397, 435, 361, 447, 356,
    # right eyebrow 17-21 (outer -> inner), left eyebrow 22-26 (inner -> outer)
    70, 63, 105, 66, 107, 336, 296, 334, 293, 300,
    # nose bridge 27-30 (top -> tip), nose base 31-35 (image left -> right)
    168, 197, 195, 4, 240, 97, 2, 326, 460,
    # right eye 36-41: outer corner, upper lid x2, inner corner, lower lid x2
    7, 160, 158, 155, 153, 144,
    # left eye 42-47: inner corner, upper lid x2, outer corner, lower lid x2
    382, 385, 387, 249, 373, 380,
    # outer lips 48-59: right corner, upper lip, left corner, lower lip
    61, 40, 72, 11, 302, 270, 291, 405, 314, 17, 84, 181,
    # inner lips 60-67: right corner, upper, left corner, lower
    62, 38, 13, 268, 292, 316, 15, 86,
], dtype=np.int32)

IBUG68_GROUPS = {
    "jaw": range(0, 17),
    "right_eyebrow": range(17, 22),
    "left_eyebrow": range(22, 27),
    "nose_bridge": range(27, 31),
    "nose_base": range(31, 36),
    "right_eye": range(36, 42),
    "left_eye": range(42, 48),
    "outer_lips": range(48, 60),
    "inner_lips": range(60, 68),
}
# Outer eye corners, the usual inter-ocular normaliser (1-based iBUG points 37 and 46).
RIGHT_EYE_OUTER, LEFT_EYE_OUTER = 36, 45


def to_ibug68(points: np.ndarray, depth: bool = False) -> np.ndarray:
    """iBUG-68 landmarks from face-mesh points.

    points: (468, 2 or 3) (or (..., 468, k) for several faces), image pixels. Returns
    (68, 2) float32 (or (..., 68, 2)) x, y in the same pixels, in iBUG order; with ``depth`` and
    3 columns given, (68, 3): the network's relative depth kept as the third.
    """
    points = np.asarray(points)
    if points.ndim < 2 or points.shape[-2] != NUM_MESH_POINTS or points.shape[-1] < 2:
        raise ValueError(f"expected face-mesh points of shape (..., {NUM_MESH_POINTS}, 2 or 3), "
                         f"got {points.shape}")
    columns = 3 if depth and points.shape[-1] >= 3 else 2
    return points[..., IBUG68_FROM_MESH, :columns].astype(np.float32)


def normalised_mean_error(predicted: np.ndarray, truth: np.ndarray) -> float:
    """Mean point distance between two (68, 2) landmark sets divided by the distance between
    the outer eye corners of ``truth`` (iBUG 37 and 46, 1-based)."""
    predicted, truth = np.asarray(predicted, np.float64), np.asarray(truth, np.float64)
    inter_ocular = np.linalg.norm(truth[RIGHT_EYE_OUTER] - truth[LEFT_EYE_OUTER])
    return float(np.linalg.norm(predicted - truth, axis=1).mean() / max(inter_ocular, 1e-9))


def dlib_annotations(path) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """The faces of a dlib landmark file (``training_with_face_landmarks.xml``): (photo file,
    box [left, top, width, height] px, points (68, 2) px, 0-based iBUG order) for each."""
    import xml.etree.ElementTree as ET

    faces = []
    for image in ET.parse(path).getroot().iter("image"):
        for box in image.iter("box"):
            points = np.zeros((68, 2))
            for part in box.iter("part"):
                points[int(part.get("name"))] = float(part.get("x")), float(part.get("y"))
            faces.append((image.get("file"), np.array([float(box.get(k)) for k in ("left", "top", "width", "height")]),
                          points))
    return faces
