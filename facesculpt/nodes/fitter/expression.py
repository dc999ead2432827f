"""Expression parameters: a compact, model-independent description of a fitted face's expression.

In the spirit of MPEG-4 facial animation parameters and FACS action units, each component is a
displacement of named facial points relative to the same person's neutral face, in model space
(x to the subject's left, y up, z out of the face), divided by the neutral's inter-ocular distance
(outer eye corners) and given in percent of it; eye closure is a fraction (0 open as in the
neutral, 1 closed). Both built-in models give the points: the face mesh through its iBUG-68
correspondence (``IBUG68_FROM_MESH`` of :mod:`facesculpt.geometry.ibug68`), the Surrey Face Model through its iBUG-68
landmark vertices; the cheeks are the models' named ``right_cheek`` / ``left_cheek``.

:data:`COMPONENTS` names every component with its unit and meaning (docs/guide/expressions.md
has the same table). :func:`expression_points` takes the points of a mesh,
:func:`expression_parameters` compares them with the neutral's.
"""

from __future__ import annotations

import numpy as np

from facesculpt.geometry.ibug68 import IBUG68_FROM_MESH, to_ibug68

#: (name, unit, what a positive value means). Units: "%IOD" percent of the neutral's
#: inter-ocular distance; "fraction" 0 (as neutral) .. 1 (fully).
COMPONENTS: tuple[tuple[str, str, str], ...] = (
    ("jaw_open", "%IOD", "inner lips apart (mouth opening)"),
    ("jaw_drop", "%IOD", "chin moved down"),
    ("jaw_left", "%IOD", "chin moved to the subject's left"),
    ("jaw_forward", "%IOD", "chin moved forward (toward the camera when frontal)"),
    ("lip_corner_up_right", "%IOD", "right mouth corner raised (smile; negative: lowered)"),
    ("lip_corner_up_left", "%IOD", "left mouth corner raised (smile; negative: lowered)"),
    ("lip_stretch_right", "%IOD", "right mouth corner pulled outward (negative: inward)"),
    ("lip_stretch_left", "%IOD", "left mouth corner pulled outward (negative: inward)"),
    ("lips_pucker", "%IOD", "lips pushed forward"),
    ("upper_lip_raise", "%IOD", "upper lip raised toward the nose"),
    ("lower_lip_depress", "%IOD", "lower lip pulled down from the chin line"),
    ("mouth_left", "%IOD", "mouth shifted to the subject's left"),
    ("brow_inner_up_right", "%IOD", "inner end of the right brow raised"),
    ("brow_inner_up_left", "%IOD", "inner end of the left brow raised"),
    ("brow_outer_up_right", "%IOD", "outer end of the right brow raised"),
    ("brow_outer_up_left", "%IOD", "outer end of the left brow raised"),
    ("brow_lower", "%IOD", "brows drawn together (frown)"),
    ("eye_close_right", "fraction", "right eyelids closed (1: shut)"),
    ("eye_close_left", "fraction", "left eyelids closed (1: shut)"),
    ("lower_lid_raise_right", "%IOD", "right lower eyelid raised (squint)"),
    ("lower_lid_raise_left", "%IOD", "left lower eyelid raised (squint)"),
    ("cheek_puff_right", "%IOD", "right cheek pushed outward"),
    ("cheek_puff_left", "%IOD", "left cheek pushed outward"),
    ("nose_wrinkle", "%IOD", "nose tip drawn up toward the bridge"),
)
NAMES: tuple[str, ...] = tuple(c[0] for c in COMPONENTS)
#: Head pose columns that go with the expression: degrees, then camera-space translation (mm).
POSE_NAMES: tuple[str, ...] = ("yaw_deg", "pitch_deg", "roll_deg", "tx_mm", "ty_mm", "tz_mm")

_CHEEKS = ("right_cheek", "left_cheek")


def expression_points(vertices: np.ndarray, dense: bool, landmark_names, landmark_vertices) -> np.ndarray:
    """(70, 3) float64: the 68 iBUG points of a mesh (row i = iBUG point i + 1; NaN where the model
    has none), then the right and left cheek. vertices (V, 3) model space, mm; dense: the face-mesh
    model (468 network points, mapped by ``IBUG68_FROM_MESH``), else iBUG numbers "1".."68" name
    the landmark vertices."""
    v = np.asarray(vertices, np.float64)
    names = {str(n): int(i) for n, i in zip(landmark_names, np.asarray(landmark_vertices).ravel())}
    out = np.full((70, 3), np.nan)
    if dense:
        out[:68] = v[IBUG68_FROM_MESH]
    else:
        for k in range(68):
            if str(k + 1) in names:
                out[k] = v[names[str(k + 1)]]
    for j, name in enumerate(_CHEEKS):
        if name in names:
            out[68 + j] = v[names[name]]
    return out


def with_landmark_residual(points: np.ndarray, observed_px: np.ndarray, R: np.ndarray, scale: float,
                           K: np.ndarray | None, camera_vertices: np.ndarray, projected_px: np.ndarray,
                           vertex_ids: np.ndarray) -> np.ndarray:
    """``points`` (70, 3) model space of a sparse model's fit, each iBUG point moved by what the
    model could not follow: the observed landmark's pixel offset from the fitted point's
    projection, taken back into model space at the point's depth (the dense residual a model with
    few expression blendshapes leaves). observed_px (68, 2) pixels; R (3, 3), scale: model to
    camera; K (3, 3) or None (orthographic: pixels are camera units); camera_vertices (V, 3),
    projected_px (V, 2): the fit; vertex_ids (68,) the iBUG points' vertices (-1: none)."""
    out = np.array(points, np.float64)
    ok = (vertex_ids >= 0) & np.all(np.isfinite(observed_px), axis=1)
    ids = vertex_ids[ok]
    res = np.asarray(observed_px, np.float64)[ok] - projected_px[ids]
    if K is not None:  # pixels -> mm at each point's depth
        res = res * (camera_vertices[ids, 2:3] / np.array([K[0, 0], K[1, 1]]))
    delta_cam = np.concatenate([res, np.zeros((len(ids), 1))], axis=1)
    out[:68][ok] += delta_cam @ np.asarray(R, np.float64) / float(scale)  # R^T applied to each row
    return out


def ibug_vertex_ids(dense: bool, landmark_names, landmark_vertices) -> np.ndarray:
    """(68,) int: the vertex of each iBUG point (-1 where the model has none)."""
    if dense:
        return np.asarray(IBUG68_FROM_MESH, np.int64)
    names = {str(n): int(i) for n, i in zip(landmark_names, np.asarray(landmark_vertices).ravel())}
    return np.array([names.get(str(k + 1), -1) for k in range(68)], np.int64)


def _p(points: np.ndarray, *ibug: int) -> np.ndarray:
    """Mean of iBUG points (1-based numbers)."""
    return points[[i - 1 for i in ibug]].mean(axis=0)


def _lid_gap(p: np.ndarray, upper: tuple[int, int], lower: tuple[int, int]) -> float:
    return float(_p(p, *upper)[1] - _p(p, *lower)[1])


def _measures(p: np.ndarray) -> np.ndarray:
    """The raw measures of one set of points (model space, mm), in :data:`COMPONENTS` order."""
    x, y, z = 0, 1, 2
    nose_base, chin = _p(p, 34), _p(p, 9)
    mouth_top, mouth_bottom = _p(p, 52), _p(p, 58)
    return np.array([
        _p(p, 63)[y] - _p(p, 67)[y],
        -chin[y],
        chin[x],
        chin[z],
        _p(p, 49)[y] - nose_base[y],
        _p(p, 55)[y] - nose_base[y],
        -_p(p, 49)[x],
        _p(p, 55)[x],
        (mouth_top[z] + mouth_bottom[z]) / 2,
        mouth_top[y] - nose_base[y],
        chin[y] - mouth_bottom[y],
        (_p(p, 49)[x] + _p(p, 55)[x]) / 2,
        _p(p, 22)[y] - _p(p, 40)[y],
        _p(p, 23)[y] - _p(p, 43)[y],
        _p(p, 18)[y] - _p(p, 37)[y],
        _p(p, 27)[y] - _p(p, 46)[y],
        -(_p(p, 23)[x] - _p(p, 22)[x]),
        _lid_gap(p, (38, 39), (41, 42)),
        _lid_gap(p, (44, 45), (47, 48)),
        _p(p, 41, 42)[y] - _p(p, 37, 40)[y],
        _p(p, 47, 48)[y] - _p(p, 43, 46)[y],
        -p[68, x],
        p[69, x],
        nose_base[y] - _p(p, 28)[y],
    ])


_EYE_CLOSE = (NAMES.index("eye_close_right"), NAMES.index("eye_close_left"))


def expression_parameters(points: np.ndarray, neutral_points: np.ndarray) -> np.ndarray:
    """(E,) float32 the components of :data:`COMPONENTS` for ``points`` against the same person's
    ``neutral_points`` (both (70, 3) from :func:`expression_points`, model space, mm): 0 for the
    neutral itself; NaN for a component whose points the model lacks."""
    cur, ref = _measures(np.asarray(points, np.float64)), _measures(np.asarray(neutral_points, np.float64))
    iod = float(np.linalg.norm(_p(neutral_points, 37) - _p(neutral_points, 46)))
    if not np.isfinite(iod) or iod <= 0:
        return np.full(len(NAMES), np.nan, np.float32)
    out = 100.0 * (cur - ref) / iod
    for k in _EYE_CLOSE:  # a fraction of the neutral's own lid gap
        out[k] = 1.0 - cur[k] / ref[k] if ref[k] > 1e-6 else np.nan
    return out.astype(np.float32)


def face_expression(fit, model, neutral: np.ndarray, observed_px: np.ndarray | None = None) -> np.ndarray:
    """(E,) float32 the expression of one fit (:class:`FitResult`) of ``model`` against the
    person's ``neutral`` (V, 3) model space, mm. observed_px: the landmarks the fit was made from,
    (468, 2|3) face-mesh points or (68, 2) iBUG, pixels; a sparse model then adds what its
    blendshapes could not follow (:func:`with_landmark_residual`), measured against the landmark
    fit itself (``fit.landmark_fit`` when the fit was refined by appearance: the refinement moves
    the head off the landmarks, and that move is not an expression)."""
    names, lv = model.landmark_names, model.landmark_vertices
    points = expression_points(fit.model_vertices, model.dense, names, lv)
    if not model.dense and observed_px is not None:
        observed = np.asarray(observed_px, np.float64)
        observed = to_ibug68(observed) if observed.shape[0] == 468 else observed[:, :2]
        by = fit if fit.landmark_fit is None else fit.landmark_fit
        points = with_landmark_residual(points, observed, by.R, by.scale, by.K, by.vertices, by.projected,
                                        ibug_vertex_ids(False, names, lv))
    return expression_parameters(points, expression_points(neutral, model.dense, names, lv))


def head_pose(fit) -> np.ndarray:
    """(6,) float64 the pose columns of :data:`POSE_NAMES`: yaw, pitch, roll (degrees), then the
    camera-space translation (mm; pixels for an orthographic fit)."""
    return np.array([*fit.yaw_pitch_roll, *np.asarray(fit.t, np.float64)[:3]])
