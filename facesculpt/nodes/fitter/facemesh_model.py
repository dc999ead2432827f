"""The built-in dense ``facemesh`` model: MediaPipe's 468-vertex face-mesh topology (the
tessellation ``facesculpt setup`` extracts), no PCA bases (in dense mode every vertex is
observed), and a neutral shape put into model space by :func:`normalise_facemesh_neutral`.

Until the fitter has learned this person's neutral from the first frames, the neutral is a
placeholder built from the tessellation alone (:func:`_placeholder_facemesh_neutral`).
"""

from __future__ import annotations

import hashlib
import os

import numpy as np

from facesculpt.geometry.boundary_loops import boundary_loops
from facesculpt.nodes.fitter.model import ModelFormatError, MorphableModel
from facesculpt.paths import model_file, model_home

#: MediaPipe face-mesh vertex of each semantic landmark (the mesh's published keypoint annotations).
FACEMESH_SEMANTIC = {
    "nose_tip": 4, "chin": 152, "forehead": 151, "right_cheek": 205, "left_cheek": 425,
    "mouth_right": 61, "mouth_left": 291, "right_eye_outer": 33, "left_eye_outer": 263,
    "right_eye_inner": 133, "left_eye_inner": 362, "right_brow": 105, "left_brow": 334,
    "nose_bridge": 168,
}

#: The facemesh model is scaled so the outer eye corners are this far apart (an adult average, mm).
FACEMESH_EYE_CORNER_MM = 90.0
FACEMESH_VERTICES = 468


def facemesh_model(neutral: np.ndarray | None = None) -> MorphableModel:
    """The built-in dense model: MediaPipe's 468-vertex face-mesh topology, tessellation from
    ``facesculpt setup`` (``facemesh_triangles.npy``). No PCA bases: in dense mode every vertex is
    observed. The neutral ``mean`` is ``neutral`` (V, 3) when given (e.g. learned from frames), else
    a placeholder built from the tessellation alone (flat, eye-corner distance 90 mm) until the
    fitter learns a neutral. Model space is scaled so the outer-eye-corner distance is
    :data:`FACEMESH_EYE_CORNER_MM`."""
    triangles = np.load(model_file("facemesh_triangles.npy"), allow_pickle=False)
    source = "facemesh tessellation from facesculpt setup"
    texcoords = np.zeros((0, 2), np.float32)
    if neutral is None:
        neutral = _stored_placeholder(triangles)
        source += "; placeholder neutral (learned from frames when fitting)"
    neutral = normalise_facemesh_neutral(np.asarray(neutral, np.float32))
    sem = {k: v for k, v in FACEMESH_SEMANTIC.items()}
    names = [str(i) for i in range(FACEMESH_VERTICES)] + list(sem.keys())
    verts = list(range(FACEMESH_VERTICES)) + list(sem.values())
    return MorphableModel(
        model_id="facemesh",
        mean=neutral,
        triangles=triangles,
        texcoords=texcoords,
        landmark_names=names,
        landmark_vertices=np.array(verts, np.int32),
        dense=True,
        units="mm",
        source=source,
    )


def normalise_facemesh_neutral(points: np.ndarray) -> np.ndarray:
    """Put a (468, 3) face-mesh shape into model space: centred on the mean of the vertices,
    rotated so x runs from the right outer eye corner (33) to the left (263) and y up
    (toward the forehead, 10), z toward the viewer, scaled to 90 mm between the eye corners."""
    p = np.asarray(points, np.float64)
    if p.shape != (FACEMESH_VERTICES, 3):
        raise ModelFormatError(f"facemesh neutral must be ({FACEMESH_VERTICES}, 3), got {p.shape}")
    if not np.isfinite(p).all():
        raise ModelFormatError("facemesh neutral contains NaN or infinite values")
    x = p[FACEMESH_SEMANTIC["left_eye_outer"]] - p[FACEMESH_SEMANTIC["right_eye_outer"]]
    dist = np.linalg.norm(x)
    if dist < 1e-9:
        raise ModelFormatError("facemesh neutral is degenerate (eye corners coincide)")
    x /= dist
    up = p[10] - p[FACEMESH_SEMANTIC["chin"]]
    y = up - x * (up @ x)
    ny = np.linalg.norm(y)
    if ny < 1e-9:
        raise ModelFormatError("facemesh neutral is degenerate (forehead-chin axis along the eye axis)")
    y /= ny
    z = np.cross(x, y)
    R = np.stack([x, y, z])
    centred = (p - p.mean(axis=0)) @ R.T
    # The nose must point to +z (toward the viewer); a mirrored input would put it behind.
    if centred[FACEMESH_SEMANTIC["nose_tip"], 2] < centred[:, 2].mean():
        raise ModelFormatError("facemesh neutral is mirrored (nose behind the face plane)")
    return (centred * (FACEMESH_EYE_CORNER_MM / dist)).astype(np.float32)


def _stored_placeholder(triangles: np.ndarray) -> np.ndarray:
    """:func:`_placeholder_facemesh_neutral` of ``triangles``, computed once and kept beside the
    tessellation in the model home (named by a hash of ``triangles``, so a new tessellation gets
    its own): every fitter start loads it instead of solving for it. Where the file cannot be
    read or written, it is computed."""
    tri = np.ascontiguousarray(triangles, np.int64)
    path = model_home() / f"facemesh_placeholder_{hashlib.sha1(tri.tobytes()).hexdigest()[:16]}.npy"
    try:
        stored = np.load(path, allow_pickle=False)
        if stored.shape == (FACEMESH_VERTICES, 3) and np.isfinite(stored).all():
            return stored
    except (OSError, ValueError):
        pass
    neutral = _placeholder_facemesh_neutral(tri)
    try:  # written whole, then renamed: a fitter starting beside this one never reads half a file
        tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npy")
        np.save(tmp, neutral, allow_pickle=False)
        os.replace(tmp, path)
    except OSError:
        pass
    return neutral


def _placeholder_facemesh_neutral(triangles: np.ndarray) -> np.ndarray:
    """A stand-in neutral before any frame: a flat 2D layout of the tessellation (Tutte embedding
    with the mesh boundary on an ellipse), bulged toward the viewer in the middle, so the model is
    valid and roughly face-shaped. Replaced by the neutral learned from the first frames."""
    V = FACEMESH_VERTICES
    tri = np.asarray(triangles, np.int64)
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    uniq = np.unique(key, axis=0)
    # The longest boundary loop is the outline (the others: eye and mouth holes).
    loops = boundary_loops(tri)
    loop = loops[0] if loops else []
    pos = np.zeros((V, 2))
    fixed = np.zeros(V, bool)
    if len(loop) >= 3:
        ang = np.linspace(0, 2 * np.pi, len(loop), endpoint=False)
        pos[loop] = np.stack([70 * np.cos(ang), 90 * np.sin(ang)], axis=1)
        fixed[loop] = True
    # The graph Laplacian, dense: 468 vertices solve in milliseconds with numpy alone (scipy's
    # import would lengthen every fitter's start-up, a respawned node's time away).
    L = np.zeros((V, V))
    L[uniq[:, 0], uniq[:, 1]] = -1.0
    L[uniq[:, 1], uniq[:, 0]] = -1.0
    L[np.arange(V), np.arange(V)] = -L.sum(axis=1)
    free = ~fixed
    if free.any() and fixed.any():
        rhs = -L[np.ix_(free, fixed)] @ pos[fixed]
        pos[free] = np.linalg.solve(L[np.ix_(free, free)], rhs)
    r2 = (pos[:, 0] / 70) ** 2 + (pos[:, 1] / 90) ** 2
    z = 40 * np.clip(1 - r2, 0, None)
    pts = np.column_stack([pos, z])
    # Orient like a face: eye corners on a horizontal line, forehead (10) up.
    try:
        return normalise_facemesh_neutral(pts)
    except ModelFormatError:
        pts[:, 0] *= -1
        try:
            return normalise_facemesh_neutral(pts)
        except ModelFormatError:
            return pts.astype(np.float32)
