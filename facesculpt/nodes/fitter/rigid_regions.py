"""The face's rigid regions (issue 46, item 3): the vertices whose skin the head carries rigidly,
so that a pose read from their pixels is not moved by an expression.

The forehead, the nose bridge and the two cheekbones; not the mouth, the eyes (they blink and
look), the nose's tip and wings, the jaw or the outline (the background shows past it). Each is
a box in a frame of the face made from the model's named landmarks (the eye corners, the brows,
the nose and the mouth corners: both the Surrey model and the face mesh name them), measured in
units of the outer eye corners' distance, so the regions follow a model's own proportions.

Arrays in, arrays out: :func:`rigid_regions` gives each vertex its region's number.
"""

from __future__ import annotations

import numpy as np

#: The regions' numbers in :func:`rigid_regions`'s labels (-1: none).
FOREHEAD, NOSE_BRIDGE, RIGHT_CHEEKBONE, LEFT_CHEEKBONE = 0, 1, 2, 3
REGION_NAMES = ("forehead", "nose bridge", "right cheekbone", "left cheekbone")
#: The named landmarks the face's frame is made of.
NAMES = ("right_eye_outer", "left_eye_outer", "right_eye_inner", "left_eye_inner", "right_brow", "left_brow",
         "nose_bridge", "nose_tip", "mouth_right", "mouth_left")
#: The boxes, in outer-eye-corner distances: the forehead from FOREHEAD_ABOVE_BROWS above the brows
#: up FOREHEAD_HEIGHT, FOREHEAD_HALF_WIDTH either side of the middle; the nose bridge
#: BRIDGE_HALF_WIDTH either side, from the brows down to BRIDGE_ABOVE_TIP above the nose's tip;
#: the cheekbones from CHEEK_BELOW_EYES below the eye corners down to the nose's tip, from
#: CHEEK_INNER to CHEEK_OUTER out from the middle.
FOREHEAD_ABOVE_BROWS, FOREHEAD_HEIGHT, FOREHEAD_HALF_WIDTH = 0.08, 0.45, 0.42
BRIDGE_HALF_WIDTH, BRIDGE_ABOVE_TIP = 0.10, 0.15
CHEEK_BELOW_EYES, CHEEK_INNER, CHEEK_OUTER = 0.12, 0.20, 0.50
#: Vertices more than this (outer-eye-corner distances) behind the outer eye corners belong to
#: the head's sides, not to the face's front.
MAX_DEPTH_BEHIND = 0.25


def has_rigid_regions(landmarks: dict[str, int]) -> bool:
    """Whether a model's named landmarks (name -> vertex) include all of :data:`NAMES`."""
    return all(name in landmarks for name in NAMES)


def rigid_regions(vertices: np.ndarray, landmarks: dict[str, int]) -> np.ndarray:
    """(V,) int8 each vertex's region (:data:`FOREHEAD` ... :data:`LEFT_CHEEKBONE`, -1: none).

    vertices: (V, 3) a neutral face in model space (any unit); landmarks: name -> vertex index,
    with every name of :data:`NAMES` (ValueError naming the missing ones otherwise)."""
    missing = [name for name in NAMES if name not in landmarks]
    if missing:
        raise ValueError(f"the model does not name the landmarks the rigid regions are made from: {missing}")
    X = np.asarray(vertices, np.float64)
    at = {name: X[int(landmarks[name])] for name in NAMES}
    across = at["left_eye_outer"] - at["right_eye_outer"]
    unit = float(np.linalg.norm(across))
    if unit <= 0:
        raise ValueError("the model's outer eye corners coincide: no face frame for the rigid regions")
    ex = across / unit
    up = (at["right_brow"] + at["left_brow"]) / 2 - (at["mouth_right"] + at["mouth_left"]) / 2
    ey = up - (up @ ex) * ex
    ey /= max(float(np.linalg.norm(ey)), 1e-12)
    ez = np.cross(ex, ey)
    local = (X - at["nose_bridge"]) @ np.column_stack([ex, ey, ez]) / unit    # (V, 3) eye distances
    height = {name: float((p - at["nose_bridge"]) @ ey / unit) for name, p in at.items()}
    depth_eye = float(((at["right_eye_outer"] + at["left_eye_outer"]) / 2 - at["nose_bridge"]) @ ez / unit)
    u, v, w = local.T
    eyes = np.mean([height[n] for n in ("right_eye_outer", "left_eye_outer", "right_eye_inner", "left_eye_inner")])
    brows, tip = (height["right_brow"] + height["left_brow"]) / 2, height["nose_tip"]
    front = w > depth_eye - MAX_DEPTH_BEHIND
    labels = np.full(len(X), -1, np.int8)
    forehead = (v > brows + FOREHEAD_ABOVE_BROWS) & (v < brows + FOREHEAD_ABOVE_BROWS + FOREHEAD_HEIGHT) & \
        (np.abs(u) < FOREHEAD_HALF_WIDTH)
    bridge = (np.abs(u) < BRIDGE_HALF_WIDTH) & (v < brows) & (v > tip + BRIDGE_ABOVE_TIP)
    cheek = (v < eyes - CHEEK_BELOW_EYES) & (v > tip) & (np.abs(u) > CHEEK_INNER) & (np.abs(u) < CHEEK_OUTER)
    labels[front & forehead] = FOREHEAD
    labels[front & bridge] = NOSE_BRIDGE
    labels[front & cheek & (u < 0)] = RIGHT_CHEEKBONE
    labels[front & cheek & (u > 0)] = LEFT_CHEEKBONE
    return labels
