"""Carry a point of one face mesh onto another face mesh, of another person or another model
(another topology), through the landmarks both name: the portable part of a preset's handle.
An offset is carried by :func:`frame_rotation`: two models' "x left, y up, z out of the face"
need not agree (the face mesh's axes come from its eye corners and forehead-chin line), and the
landmarks both name show how one model's axes lie in the other's.

A preset stores the named landmarks of the neutral it was made on and, for a handle that is no
named landmark, the handle's rest position. On another mesh a smooth 3D warp that takes the
preset's landmarks onto this mesh's landmarks (an affine map plus a biharmonic radial-basis
correction, fitted in face-size units with a little smoothing, so that landmarks the two
models place a little differently do not fold the map) carries the point over, and the handle
is the vertex nearest to it.

Only descriptive landmark names count (``nose_tip``, ``left_eye_outer``, ...): purely numeric
names are model-specific (mesh indices in ``facemesh``, iBUG-68 numbers in the Surrey Face
Model) and mean different points on different models.
"""

from __future__ import annotations

import numpy as np

from .errors import DeformerError

#: The two landmarks whose distance is the face size (mm in both built-in models).
FACE_SIZE_LANDMARKS = ("right_eye_outer", "left_eye_outer")
#: Fewer shared landmarks than this cannot place a 3D affine map.
MIN_SHARED = 4
#: Smoothing of the radial-basis warp, in face-size units (0: through every landmark exactly).
SMOOTHING = 0.3


def portable_landmarks(landmarks: dict[str, int]) -> dict[str, int]:
    """The descriptive (not purely numeric) names of ``landmarks`` (name -> vertex): the names
    that mean the same point on every model."""
    return {str(k): int(v) for k, v in landmarks.items() if not str(k).isdigit()}


def landmark_positions(vertices: np.ndarray, landmarks: dict[str, int]) -> dict[str, np.ndarray]:
    """Name -> (3,) float64 position on the mesh ``vertices`` (V, 3) of every portable landmark."""
    V = np.asarray(vertices, dtype=np.float64)
    return {k: V[v].copy() for k, v in portable_landmarks(landmarks).items()}


def face_size(positions: dict[str, np.ndarray]) -> float | None:
    """Distance between the outer eye corners (units of the positions, mm), or None when they
    are not both named or coincide."""
    a, b = FACE_SIZE_LANDMARKS
    if a not in positions or b not in positions:
        return None
    d = float(np.linalg.norm(np.asarray(positions[a], np.float64) - np.asarray(positions[b], np.float64)))
    return d if np.isfinite(d) and d > 1e-9 else None


def warp_points(points: np.ndarray, source: dict[str, np.ndarray], target: dict[str, np.ndarray]) -> np.ndarray:
    """Points (N, 3) placed relative to the landmark positions ``source`` (name -> (3,)) carried
    to where the same landmarks are in ``target``: (N, 3) float64, units of ``target``.
    DeformerError in one sentence when the two share too few landmarks or no face size."""
    from scipy.interpolate import RBFInterpolator

    names = sorted(set(source) & set(target))
    if len(names) < MIN_SHARED:
        raise DeformerError(f"the preset and this model share {len(names)} named landmarks ({', '.join(names) or 'none'}); "
                            f"placing a handle that is not a landmark needs {MIN_SHARED}")
    s_src, s_dst = face_size(source), face_size(target)
    if s_src is None or s_dst is None:
        raise DeformerError("placing a handle that is not a landmark needs both outer eye corners "
                            f"({' and '.join(FACE_SIZE_LANDMARKS)}) in the preset and in this model")
    A = np.array([source[k] for k in names], dtype=np.float64) / s_src
    B = np.array([target[k] for k in names], dtype=np.float64) / s_dst
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3) / s_src
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(P))):
        raise DeformerError("the preset's landmark or handle positions are not finite numbers")
    try:
        warp = RBFInterpolator(A, B, kernel="linear", smoothing=SMOOTHING, degree=1)
    except (ValueError, np.linalg.LinAlgError):
        raise DeformerError(f"the landmarks {', '.join(names)} are degenerate (coplanar): cannot place the handle") from None
    return warp(P) * s_dst


def frame_rotation(source: dict[str, np.ndarray], target: dict[str, np.ndarray]) -> np.ndarray:
    """(3, 3) float64 rotation that best takes the landmark positions ``source`` (name -> (3,), the
    mesh a preset was made on) onto the same landmarks in ``target`` (name -> (3,), this mesh's
    :func:`landmark_positions`, portable names only): a similarity fit of the names both have, so
    ``rotation @ offset`` is a preset's offset in this mesh's axes. The identity when they share
    fewer than MIN_SHARED or are degenerate."""
    from facesculpt.geometry.similarity import similarity_procrustes

    names = sorted(set(source) & set(target))
    if len(names) < MIN_SHARED:
        return np.eye(3)
    A = np.array([source[k] for k in names], dtype=np.float64)
    B = np.array([target[k] for k in names], dtype=np.float64)
    if not (np.isfinite(A).all() and np.isfinite(B).all()):
        return np.eye(3)
    try:
        return similarity_procrustes(A, B)[1]
    except ValueError:
        return np.eye(3)


def nearest_vertices(vertices: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Index (N,) int64 of the vertex of ``vertices`` (V, 3) nearest to each of ``points`` (N, 3)."""
    from scipy.spatial import cKDTree

    return cKDTree(np.asarray(vertices, dtype=np.float64)).query(np.asarray(points, np.float64).reshape(-1, 3))[1]
