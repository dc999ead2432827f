"""The morphable-model format: :class:`MorphableModel` in memory, its validation, and the ``.npz``
file it is saved to and loaded from. Models come from eos files (:mod:`.eos_import`) or are
built in (:mod:`.facemesh_model`).

A model is  M(alpha, beta) = mean + shape_basis · (shape_std ∘ alpha) + expression_basis · (expression_std ∘ beta)
(paper Eq. 1), with alpha and beta in units of standard deviations (alpha ~ N(0, I)).

``.npz`` format, version 1 (``numpy.savez``, no pickled objects; strings are numpy unicode arrays)
-------------------------------------------------------------------------------------------------
=========================  ==============  ==========================================================
key                        shape / dtype   meaning
=========================  ==============  ==========================================================
format                     () str          ``"facesculpt-morphable-model"``
format_version             () int          1
model_id                   () str          short name, e.g. ``"sfm_shape_3448"``, ``"facemesh"``
units                      () str          length unit of model space, ``"mm"``
mean                       (V, 3) f4       neutral mean shape, model space (x: subject's left,
                                           y: up, z: out of the face toward the viewer)
triangles                  (T, 3) i4       vertex indices, counter-clockwise seen from the front
shape_basis                (V, 3, S) f4    orthonormal principal directions (each (V,3) slice a unit
                                           vector of length 3V)
shape_std                  (S,) f4         standard deviation of each component (sqrt eigenvalue)
expression_kind            () str          ``"none"``, ``"blendshapes"`` or ``"pca"``
expression_basis           (V, 3, E) f4    blendshape offsets (blendshapes) or orthonormal directions (pca)
expression_std             (E,) f4         1 for blendshapes, sqrt eigenvalue for pca
expression_names           (E,) str        e.g. ``"happiness"``
expression_lower/_upper    (E,) f4         coefficient bounds (blendshapes: [0, inf) as in eos' NNLS)
texcoords                  (V, 2) f4       per-vertex texture coordinates in [0, 1]; (0, 2) when absent
landmark_names             (L,) str        named landmarks (see below)
landmark_vertices          (L,) i4         vertex of each named landmark
outline_right/_left        (N,) i4         model vertices along the subject's right / left face outline,
                                           candidates for the outline landmarks
outline_landmarks_right/_left (K,) str     landmark names that lie on each outline (not tied to vertices)
dense                      () bool         every vertex is observed directly (facemesh dense mode)
landmark_offsets           (L, 3) f4       optional calibration: where the landmark network's point for
                                           each named landmark lies, model mm from its vertex; (0, 3)
                                           when absent (the vertex itself)
landmark_weights           (L,) f4         optional calibration: each landmark's weight in the fit
                                           (1/sigma², mean 1); (0,) when absent (all 1)
network_rotation_gain      (3,) f4         optional calibration: the landmark network's own 3D points turn
                                           by 1/gain of the head about the camera's x (pitch), y (yaw) and
                                           z axes; (0,) when absent (gain 1)
calibration                () str          where the calibration came from (empty: none)
source                     () str          free text: where the model came from
=========================  ==============  ==========================================================

Landmark names. A model from an eos mapping keeps its names (for ``ibug_to_sfm.txt``: the iBUG-68
numbers ``"1"``..``"68"``, 1-based, except the outline points 1-8 / 10-17 and the inner mouth
corners 61 / 65 which have no fixed vertex). Every built-in and imported face model also gets
these semantic names, which the deformer's presets use for handles ("left"/"right" are the
subject's): ``nose_tip``, ``chin``, ``forehead``, ``left_cheek``, ``right_cheek``,
``mouth_left``, ``mouth_right``, ``left_eye_outer``, ``right_eye_outer``, ``left_eye_inner``,
``right_eye_inner``, ``left_brow``, ``right_brow``, ``nose_bridge``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

FORMAT_NAME = "facesculpt-morphable-model"
FORMAT_VERSION = 1

#: Semantic landmark names every face model exposes ("left"/"right" are the subject's).
SEMANTIC_LANDMARKS = (
    "nose_tip", "chin", "forehead", "left_cheek", "right_cheek", "mouth_left", "mouth_right",
    "left_eye_outer", "right_eye_outer", "left_eye_inner", "right_eye_inner",
    "left_brow", "right_brow", "nose_bridge",
)


class ModelFormatError(ValueError):
    """A morphable-model file or array set is malformed; the message names the field and what is wrong."""


@dataclass
class MorphableModel:
    """A 3D morphable face model in memory; see the module docstring for every field's shape and units."""

    model_id: str
    mean: np.ndarray
    triangles: np.ndarray
    shape_basis: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 0), np.float32))
    shape_std: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    expression_kind: str = "none"
    expression_basis: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 0), np.float32))
    expression_std: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    expression_names: list[str] = field(default_factory=list)
    expression_lower: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    expression_upper: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    texcoords: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    landmark_names: list[str] = field(default_factory=list)
    landmark_vertices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    outline_right: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    outline_left: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    outline_landmarks_right: list[str] = field(default_factory=list)
    outline_landmarks_left: list[str] = field(default_factory=list)
    dense: bool = False
    units: str = "mm"
    source: str = ""
    landmark_offsets: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    landmark_weights: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    network_rotation_gain: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    calibration: str = ""

    def __post_init__(self) -> None:
        V = int(np.asarray(self.mean).shape[0]) if np.ndim(self.mean) == 2 else 0
        if np.size(self.shape_basis) == 0:
            self.shape_basis = np.zeros((V, 3, 0), np.float32)
        if np.size(self.expression_basis) == 0 and self.expression_kind == "none":
            self.expression_basis = np.zeros((V, 3, 0), np.float32)
        validate(self)

    # -- sizes -------------------------------------------------------------------------------
    @property
    def num_vertices(self) -> int:
        return int(self.mean.shape[0])

    @property
    def num_shape(self) -> int:
        return int(self.shape_std.shape[0])

    @property
    def num_expression(self) -> int:
        return int(self.expression_std.shape[0])

    # -- instances ---------------------------------------------------------------------------
    def landmark_index(self) -> dict[str, int]:
        """Landmark name -> vertex index."""
        return dict(zip(self.landmark_names, (int(v) for v in self.landmark_vertices)))

    def instance(self, alpha: np.ndarray | None = None, beta: np.ndarray | None = None) -> np.ndarray:
        """Vertices (V, 3) float32, model space, for shape ``alpha`` (S,) and expression ``beta`` (E,)
        coefficients in standard deviations (missing trailing coefficients are zero)."""
        shape = self.mean.astype(np.float32).copy()
        if alpha is not None and len(alpha):
            a = np.asarray(alpha, np.float32)
            shape += basis_combination(self.shape_basis[:, :, : len(a)], self.shape_std[: len(a)] * a)
        if beta is not None and len(beta):
            b = np.asarray(beta, np.float32)
            shape += basis_combination(self.expression_basis[:, :, : len(b)], self.expression_std[: len(b)] * b)
        return shape

    def with_mean(self, mean: np.ndarray, source: str | None = None) -> MorphableModel:
        """A copy with another neutral mean (V, 3) (e.g. a learned per-person reference)."""
        return replace(self, mean=np.asarray(mean, np.float32), source=self.source if source is None else source)


def basis_combination(basis: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """(V, 3): ``basis`` (V, 3, k) weighted by ``coefficients`` (k,), as one (3V, k) matrix times a
    vector (``basis @ coefficients`` is a product batched over the vertices, several times slower)."""
    V, _, k = basis.shape
    return (basis.reshape(3 * V, k) @ coefficients).reshape(V, 3)


def _fail(what: str) -> None:
    raise ModelFormatError(what)


def validate(model: MorphableModel) -> None:
    """Check every array's shape, dtype range and index bounds; raise :class:`ModelFormatError` naming the field."""
    m = model
    m.mean = np.asarray(m.mean, dtype=np.float32)
    if m.mean.ndim != 2 or m.mean.shape[1] != 3 or m.mean.shape[0] < 3:
        _fail(f"mean must be (V, 3) with V >= 3, got {m.mean.shape}")
    if not np.isfinite(m.mean).all():
        _fail("mean contains NaN or infinite values")
    V = m.mean.shape[0]
    m.triangles = np.asarray(m.triangles)
    if m.triangles.ndim != 2 or m.triangles.shape[1] != 3 or m.triangles.shape[0] < 1:
        _fail(f"triangles must be (T, 3) with T >= 1, got {m.triangles.shape}")
    if not np.issubdtype(m.triangles.dtype, np.integer):
        _fail(f"triangles must be integers, got {m.triangles.dtype}")
    m.triangles = m.triangles.astype(np.int32)
    if m.triangles.min() < 0 or m.triangles.max() >= V:
        _fail(f"triangles index vertices {m.triangles.min()}..{m.triangles.max()} but the mean has {V} vertices")
    for name in ("shape", "expression"):
        basis = np.asarray(getattr(m, f"{name}_basis"), dtype=np.float32)
        std = np.asarray(getattr(m, f"{name}_std"), dtype=np.float32).reshape(-1)
        if basis.ndim != 3 or basis.shape[0] != V or basis.shape[1] != 3:
            _fail(f"{name}_basis must be (V={V}, 3, K), got {basis.shape}")
        if basis.shape[2] != std.shape[0]:
            _fail(f"{name}_basis has {basis.shape[2]} components but {name}_std has {std.shape[0]} values")
        if not (np.isfinite(basis).all() and np.isfinite(std).all()):
            _fail(f"{name}_basis or {name}_std contains NaN or infinite values")
        if (std <= 0).any():
            _fail(f"{name}_std must be positive (a standard deviation per component)")
        setattr(m, f"{name}_basis", basis)
        setattr(m, f"{name}_std", std)
    E = m.expression_std.shape[0]
    if m.expression_kind not in ("none", "blendshapes", "pca"):
        _fail(f"expression_kind must be 'none', 'blendshapes' or 'pca', got {m.expression_kind!r}")
    if m.expression_kind == "none" and E:
        _fail(f"expression_kind is 'none' but there are {E} expression components")
    m.expression_names = [str(s) for s in m.expression_names] or [f"expression_{i}" for i in range(E)]
    if len(m.expression_names) != E:
        _fail(f"expression_names has {len(m.expression_names)} names for {E} components")
    default_lo = 0.0 if m.expression_kind == "blendshapes" else -np.inf
    m.expression_lower = np.asarray(m.expression_lower, np.float32).reshape(-1) if np.size(m.expression_lower) else np.full(E, default_lo, np.float32)
    m.expression_upper = np.asarray(m.expression_upper, np.float32).reshape(-1) if np.size(m.expression_upper) else np.full(E, np.inf, np.float32)
    if m.expression_lower.shape != (E,) or m.expression_upper.shape != (E,):
        _fail(f"expression_lower/upper must be ({E},), got {m.expression_lower.shape} / {m.expression_upper.shape}")
    if (m.expression_lower > m.expression_upper).any():
        _fail("expression_lower exceeds expression_upper")
    m.texcoords = np.asarray(m.texcoords, np.float32).reshape(-1, 2) if np.size(m.texcoords) else np.zeros((0, 2), np.float32)
    if m.texcoords.shape[0] not in (0, V):
        _fail(f"texcoords must be (V={V}, 2) or empty, got {m.texcoords.shape}")
    m.landmark_names = [str(s) for s in m.landmark_names]
    m.landmark_vertices = np.asarray(m.landmark_vertices).reshape(-1).astype(np.int32)
    if len(m.landmark_names) != m.landmark_vertices.shape[0]:
        _fail(f"{len(m.landmark_names)} landmark_names but {m.landmark_vertices.shape[0]} landmark_vertices")
    if len(set(m.landmark_names)) != len(m.landmark_names):
        _fail("landmark_names contains duplicates")
    if m.landmark_vertices.size and (m.landmark_vertices.min() < 0 or m.landmark_vertices.max() >= V):
        _fail(f"landmark_vertices must index the {V} vertices")
    for side in ("right", "left"):
        outline = np.asarray(getattr(m, f"outline_{side}")).reshape(-1).astype(np.int32)
        if outline.size and (outline.min() < 0 or outline.max() >= V):
            _fail(f"outline_{side} must index the {V} vertices")
        setattr(m, f"outline_{side}", outline)
        names = [str(s) for s in getattr(m, f"outline_landmarks_{side}")]
        if names and not outline.size:
            _fail(f"outline_landmarks_{side} is given but outline_{side} has no vertices")
        setattr(m, f"outline_landmarks_{side}", names)
    _validate_calibration(m)
    if not isinstance(m.units, str) or not m.units:
        _fail("units must be a non-empty string such as 'mm'")
    m.dense = bool(m.dense)


def _validate_calibration(m: MorphableModel) -> None:
    """The optional landmark calibration's fields (module docstring), normalised in place."""
    L = len(m.landmark_names)
    m.landmark_offsets = np.asarray(m.landmark_offsets, np.float32).reshape(-1, 3)
    m.landmark_weights = np.asarray(m.landmark_weights, np.float32).reshape(-1)
    if m.landmark_offsets.shape[0] not in (0, L) or m.landmark_weights.shape[0] not in (0, L):
        _fail(f"landmark_offsets must be ({L}, 3) and landmark_weights ({L},) or empty, "
              f"got {m.landmark_offsets.shape} / {m.landmark_weights.shape}")
    if not (np.isfinite(m.landmark_offsets).all() and np.isfinite(m.landmark_weights).all()
            and (m.landmark_weights > 0).all()):
        _fail("landmark_offsets must be finite and landmark_weights finite and positive")
    m.network_rotation_gain = np.asarray(m.network_rotation_gain, np.float32).reshape(-1)
    if m.network_rotation_gain.shape[0] not in (0, 3) or not (m.network_rotation_gain > 0).all():
        _fail(f"network_rotation_gain must be 3 positive gains or empty, got {m.network_rotation_gain}")
    m.calibration = str(m.calibration)


# --------------------------------------------------------------------------------------------
# .npz files


def save_model(model: MorphableModel, path: str | Path) -> Path:
    """Write ``model`` to ``path`` in the documented ``.npz`` format; returns the path."""
    validate(model)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    s = lambda items: np.asarray(list(items), dtype=np.str_) if len(items) else np.zeros(0, dtype="<U1")  # noqa: E731
    with open(path, "wb") as fh:
        np.savez(
            fh,
            format=np.str_(FORMAT_NAME),
            format_version=np.int64(FORMAT_VERSION),
            model_id=np.str_(model.model_id),
            units=np.str_(model.units),
            source=np.str_(model.source),
            mean=model.mean,
            triangles=model.triangles,
            shape_basis=model.shape_basis,
            shape_std=model.shape_std,
            expression_kind=np.str_(model.expression_kind),
            expression_basis=model.expression_basis,
            expression_std=model.expression_std,
            expression_names=s(model.expression_names),
            expression_lower=model.expression_lower,
            expression_upper=model.expression_upper,
            texcoords=model.texcoords,
            landmark_names=s(model.landmark_names),
            landmark_vertices=model.landmark_vertices,
            outline_right=model.outline_right,
            outline_left=model.outline_left,
            outline_landmarks_right=s(model.outline_landmarks_right),
            outline_landmarks_left=s(model.outline_landmarks_left),
            dense=np.bool_(model.dense),
            landmark_offsets=model.landmark_offsets,
            landmark_weights=model.landmark_weights,
            network_rotation_gain=model.network_rotation_gain,
            calibration=np.str_(model.calibration),
        )
    return path


_REQUIRED = ("format", "format_version", "model_id", "mean", "triangles")


def load_npz(path: Path) -> MorphableModel:
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ModelFormatError(f"{path}: not a readable .npz file ({exc})") from exc
    with data:
        keys = set(data.files)
        missing = [k for k in _REQUIRED if k not in keys]
        if missing:
            raise ModelFormatError(f"{path}: not a facesculpt model, missing {', '.join(missing)}")
        if str(data["format"]) != FORMAT_NAME:
            raise ModelFormatError(f"{path}: format is {str(data['format'])!r}, expected {FORMAT_NAME!r}")
        version = int(data["format_version"])
        if version > FORMAT_VERSION:
            raise ModelFormatError(f"{path}: format_version {version} is newer than this reader ({FORMAT_VERSION})")
        get = lambda k, default=None: data[k] if k in keys else default  # noqa: E731
        strs = lambda k: [str(x) for x in get(k, np.zeros(0, "<U1")).tolist()]  # noqa: E731
        kwargs = dict(
            model_id=str(data["model_id"]),
            mean=data["mean"],
            triangles=data["triangles"],
            shape_basis=get("shape_basis", np.zeros((0, 3, 0), np.float32)),
            shape_std=get("shape_std", np.zeros(0, np.float32)),
            expression_kind=str(get("expression_kind", "none")),
            expression_basis=get("expression_basis", np.zeros((0, 3, 0), np.float32)),
            expression_std=get("expression_std", np.zeros(0, np.float32)),
            expression_names=strs("expression_names"),
            expression_lower=get("expression_lower", np.zeros(0, np.float32)),
            expression_upper=get("expression_upper", np.zeros(0, np.float32)),
            texcoords=get("texcoords", np.zeros((0, 2), np.float32)),
            landmark_names=strs("landmark_names"),
            landmark_vertices=get("landmark_vertices", np.zeros(0, np.int32)),
            outline_right=get("outline_right", np.zeros(0, np.int32)),
            outline_left=get("outline_left", np.zeros(0, np.int32)),
            outline_landmarks_right=strs("outline_landmarks_right"),
            outline_landmarks_left=strs("outline_landmarks_left"),
            dense=bool(get("dense", False)),
            units=str(get("units", "mm")),
            source=str(get("source", "")),
            landmark_offsets=get("landmark_offsets", np.zeros((0, 3), np.float32)),
            landmark_weights=get("landmark_weights", np.zeros(0, np.float32)),
            network_rotation_gain=get("network_rotation_gain", np.zeros(0, np.float32)),
            calibration=str(get("calibration", "")),
        )
    try:
        return MorphableModel(**kwargs)
    except ModelFormatError as exc:
        raise ModelFormatError(f"{path}: {exc}") from None
