"""Synthetic ground truth for the fitter (tests and benchmarks): random faces of a model, posed and projected, with 68 iBUG
landmarks whose outline points come from the true silhouette of the posed face (not fixed vertices).

Outline landmarks. iBUG 1-8 (subject's right) and 10-17 (left) are placed as an annotator places
them: evenly along the visible outline of the posed face, from the chin up to the height of the
face's centre. The outline on each side is traced by image rays from the projected centre (on the
midline 15 mm below the eyes, at the landmarks' mean depth) in the projections of the model-space
directions from straight down to horizontal: each ray's last exit from the projected face (without
the protruding nose, :func:`_without_nose`). So the outline points fall wherever the silhouette lies
on the mesh, never on fixed vertices. Landmarks with a fixed model vertex are that vertex projected.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesculpt.geometry.projection import project as project_points
from facesculpt.geometry.projection import project_orthographic
from facesculpt.nodes.fitter.model import MorphableModel
from facesculpt.nodes.fitter.outline import nose_region
from facesculpt.nodes.fitter.pose import rotation_from_euler

OUTLINE_RIGHT = [str(k) for k in range(1, 9)]
OUTLINE_LEFT = [str(k) for k in range(10, 18)]


@dataclass
class SyntheticFace:
    """One synthetic sample. alpha (S,), beta (E,); R (3, 3); t (3,); s px/mm (orthographic) or
    K (3, 3) (perspective, t in mm); vertices (V, 3) model space mm; ids (68,) str "1".."68";
    clean / noisy (68, 2) landmark pixels (NaN where the model has no such landmark, 61 and 65);
    yaw, pitch, roll in degrees."""

    alpha: np.ndarray
    beta: np.ndarray
    R: np.ndarray
    t: np.ndarray
    s: float
    K: np.ndarray | None
    vertices: np.ndarray
    ids: list[str]
    clean: np.ndarray
    noisy: np.ndarray
    yaw: float
    pitch: float
    roll: float


def ray_exit_points(
    vertices: np.ndarray, triangles: np.ndarray, centre: np.ndarray, directions: np.ndarray, project
) -> np.ndarray:
    """(D, 2) pixel positions where the image rays from the projected ``centre`` (3,) along the
    projections of the model-space ``directions`` (D, 3) leave the projected mesh for the last time —
    the posed face's outline in those directions (NaN where a ray misses the mesh).
    vertices (V, 3) model space; ``project`` maps (N, 3) model points to (N, 2) pixels."""
    uv = project(vertices)
    c2 = project(centre[None])[0]
    d2 = project(centre + 10.0 * directions) - c2
    d2 /= np.linalg.norm(d2, axis=1, keepdims=True) + 1e-12
    edges = np.unique(np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), 1), axis=0)
    a, b = uv[edges[:, 0]], uv[edges[:, 1]]
    e = b - a  # (E, 2)
    r = a - c2
    # c2 + lam d = a + mu e  (solved per ray and edge by Cramer's rule)
    det = d2[:, None, 1] * e[None, :, 0] - d2[:, None, 0] * e[None, :, 1]  # (D, E)
    ok = np.abs(det) > 1e-12
    det = np.where(ok, det, 1.0)
    lam = (r[None, :, 1] * e[None, :, 0] - r[None, :, 0] * e[None, :, 1]) / det
    mu = (d2[:, None, 0] * r[None, :, 1] - d2[:, None, 1] * r[None, :, 0]) / -det
    hit = ok & (mu >= 0) & (mu <= 1) & (lam > 0)
    far = np.where(hit, lam, -np.inf).max(axis=1)
    out = c2 + far[:, None] * d2
    out[~np.isfinite(far)] = np.nan
    return out


def outline_landmarks(vertices: np.ndarray, triangles: np.ndarray, centre: np.ndarray, project) -> dict[str, np.ndarray]:
    """True image positions of the outline landmarks (see the module docstring): for each side, the
    outline traced by rays at 1° steps from straight down (0°) to horizontal (90°), and landmarks
    spaced evenly along its length — the chin end excluded (that is landmark 9), the top end being
    landmark 1 (right) or 17 (left)."""
    phi = np.radians(np.arange(0, 91))
    out = {}
    for names, side in ((OUTLINE_RIGHT, -1.0), (OUTLINE_LEFT[::-1], 1.0)):
        dirs = np.column_stack([side * np.sin(phi), -np.cos(phi), np.zeros_like(phi)])
        curve = ray_exit_points(vertices, triangles, centre, dirs, project)
        curve = curve[np.isfinite(curve).all(axis=1)]
        seg = np.linalg.norm(np.diff(curve, axis=0), axis=1)
        arc = np.r_[0.0, np.cumsum(seg)]
        # names run from the top (1 or 17) toward the chin: fractions 8/8 .. 1/8 of the length.
        for j, name in enumerate(names):
            frac = (len(names) - j) / len(names)
            target = frac * arc[-1]
            out[name] = np.array([np.interp(target, arc, curve[:, 0]), np.interp(target, arc, curve[:, 1])])
    return out


def _without_nose(model: MorphableModel, V: np.ndarray) -> np.ndarray:
    """Triangles of the face without the protruding nose (:func:`.outline.nose_region`): the outline
    is the cheek and jaw line, as annotators mark it even where the nose juts out past it."""
    nose = nose_region(V, model.landmark_index())
    return model.triangles[~nose[model.triangles].any(axis=1)]


def make_face(
    model: MorphableModel,
    rng: np.random.Generator,
    yaw: float | None = None,
    pitch: float | None = None,
    roll: float | None = None,
    alpha_range: float = 2.0,
    beta_max: float = 0.5,
    noise_px: float = 1.0,
    image_size: tuple[int, int] = (640, 480),
    scale_range: tuple[float, float] = (1.2, 2.0),
    K: np.ndarray | None = None,
    distance_mm: float = 600.0,
    alpha: np.ndarray | None = None,
) -> SyntheticFace:
    """A random face: alpha uniform in ±alpha_range sigma (all components), each blendshape weight
    uniform in [0, beta_max], yaw ±60°, pitch ±20°, roll ±10° unless given; scaled orthographic with
    s uniform in ``scale_range`` px/mm, or perspective through K at ``distance_mm``; Gaussian
    landmark noise of ``noise_px`` px per coordinate; ``alpha`` fixes the identity (same person)."""
    S, E = model.num_shape, model.num_expression
    alpha = rng.uniform(-alpha_range, alpha_range, S).astype(np.float32) if alpha is None else np.asarray(alpha, np.float32)
    beta = rng.uniform(0, beta_max, E).astype(np.float32) if E else np.zeros(0, np.float32)
    yaw = rng.uniform(-60, 60) if yaw is None else yaw
    pitch = rng.uniform(-20, 20) if pitch is None else pitch
    roll = rng.uniform(-10, 10) if roll is None else roll
    R = rotation_from_euler(yaw, pitch, roll)
    V = model.instance(alpha, beta).astype(np.float64)
    W, H = image_size
    if K is None:
        s = float(rng.uniform(*scale_range))
        t = np.array([W / 2 + rng.uniform(-30, 30), H / 2 + rng.uniform(-30, 30), 0.0])
        project = lambda X: project_orthographic(X, R, t, s)  # noqa: E731
    else:
        s = 1.0
        t = np.array([rng.uniform(-30, 30), rng.uniform(-30, 30), distance_mm])
        project = lambda X: project_points(X @ R.T + t, K)  # noqa: E731
    idx = model.landmark_index()
    ids = [str(k) for k in range(1, 69)]
    clean = np.full((68, 2), np.nan)
    # Slice centre: midline, at the mean height of the outline's top and the chin's top.
    eye_y = 0.5 * (V[idx["37"], 1] + V[idx["46"], 1]) if "37" in idx else V[:, 1].mean()
    face_z = V[list(idx.values()), 2].mean()
    centre = np.array([0.5 * (V[idx["37"], 0] + V[idx["46"], 0]) if "37" in idx else 0.0, eye_y - 15.0, face_z])
    outline = outline_landmarks(V, _without_nose(model, V), centre, project)
    for i, k in enumerate(ids):
        if k in outline:
            clean[i] = outline[k]
        elif k in idx:
            clean[i] = project(V[idx[k]][None])[0]
    noisy = clean + rng.normal(0, noise_px, clean.shape)
    return SyntheticFace(alpha, beta, R, t, s, K, V.astype(np.float32), ids, clean, noisy, float(yaw), float(pitch), float(roll))


def similarity_aligned_error(fitted: np.ndarray, truth: np.ndarray) -> float:
    """Mean per-vertex distance (model units, mm) after the similarity transform that best aligns
    ``fitted`` (V, 3) to ``truth`` (V, 3)."""
    from facesculpt.nodes.fitter.pose import similarity_procrustes

    s, R, t = similarity_procrustes(fitted, truth)
    return float(np.linalg.norm(s * fitted @ R.T + t - truth, axis=1).mean())


def landmark_reprojection_error(projected: np.ndarray, model: MorphableModel, ids: list[str], points: np.ndarray) -> float:
    """Mean distance (px) between the input landmarks that have a fixed model vertex and that vertex
    of the fitted mesh projected (V, 2) — the same measure for every fitter."""
    idx = model.landmark_index()
    use = [i for i, k in enumerate(ids) if k in idx and np.isfinite(points[i]).all()]
    verts = [idx[ids[i]] for i in use]
    return float(np.linalg.norm(projected[verts] - points[use], axis=1).mean())
