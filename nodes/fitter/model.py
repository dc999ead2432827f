"""The morphable-model file format (``.npz``), its loader/saver, the eos importer, and the
built-in ``facemesh`` model.

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

from facesculpt.geometry.boundary_loops import boundary_loops
from facesculpt.nodes.fitter import eos_reader
from facesculpt.paths import model_file, shared_data_dir

FORMAT_NAME = "facesculpt-morphable-model"
FORMAT_VERSION = 1

#: Semantic landmark names every face model exposes ("left"/"right" are the subject's).
SEMANTIC_LANDMARKS = (
    "nose_tip", "chin", "forehead", "left_cheek", "right_cheek", "mouth_left", "mouth_right",
    "left_eye_outer", "right_eye_outer", "left_eye_inner", "right_eye_inner",
    "left_brow", "right_brow", "nose_bridge",
)

#: iBUG-68 numbers (1-based) of the semantic landmarks that have an iBUG counterpart.
IBUG_SEMANTIC = {
    "nose_tip": "31", "chin": "9", "mouth_right": "49", "mouth_left": "55",
    "right_eye_outer": "37", "right_eye_inner": "40", "left_eye_inner": "43", "left_eye_outer": "46",
    "right_brow": "20", "left_brow": "25", "nose_bridge": "28",
}

#: MediaPipe face-mesh vertex of each semantic landmark (the mesh's published keypoint annotations).
FACEMESH_SEMANTIC = {
    "nose_tip": 1, "chin": 152, "forehead": 151, "right_cheek": 205, "left_cheek": 425,
    "mouth_right": 61, "mouth_left": 291, "right_eye_outer": 33, "left_eye_outer": 263,
    "right_eye_inner": 133, "left_eye_inner": 362, "right_brow": 105, "left_brow": 334,
    "nose_bridge": 168,
}

#: The facemesh model is scaled so the outer eye corners are this far apart (an adult average, mm).
FACEMESH_EYE_CORNER_MM = 90.0
FACEMESH_VERTICES = 468


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
            shape += self.shape_basis[:, :, : len(a)] @ (self.shape_std[: len(a)] * a)
        if beta is not None and len(beta):
            b = np.asarray(beta, np.float32)
            shape += self.expression_basis[:, :, : len(b)] @ (self.expression_std[: len(b)] * b)
        return shape

    def with_mean(self, mean: np.ndarray, source: str | None = None) -> "MorphableModel":
        """A copy with another neutral mean (V, 3) (e.g. a learned per-person reference)."""
        return replace(self, mean=np.asarray(mean, np.float32), source=self.source if source is None else source)


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
    if not isinstance(m.units, str) or not m.units:
        _fail("units must be a non-empty string such as 'mm'")
    m.dense = bool(m.dense)


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
        )
    return path


_REQUIRED = ("format", "format_version", "model_id", "mean", "triangles")


def _load_npz(path: Path) -> MorphableModel:
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
        )
    try:
        return MorphableModel(**kwargs)
    except ModelFormatError as exc:
        raise ModelFormatError(f"{path}: {exc}") from None


def load_model(name_or_path: str | Path = "facemesh") -> MorphableModel:
    """Load a model: ``"facemesh"`` (built-in, needs `facesculpt setup`), ``"sfm"`` (imported on the
    fly from the shared SFM files, for tests/benchmarks), or a path to a ``.npz`` model file.
    Raises FileNotFoundError / :class:`ModelFormatError` with a message saying what is wrong."""
    if isinstance(name_or_path, MorphableModel):
        return name_or_path
    text = str(name_or_path)
    if text == "facemesh":
        return facemesh_model()
    if text == "sfm":
        return sfm_from_shared()
    path = Path(text).expanduser()
    if not path.is_file():
        raise FileNotFoundError(
            f"model {text!r} not found: give 'facemesh', or a .npz made by `facesculpt model import-eos`"
        )
    if path.suffix == ".bin":
        raise ModelFormatError(f"{path} is an eos binary: convert it first with `facesculpt model import-eos {path} -o MODEL.npz`")
    return _load_npz(path)


# --------------------------------------------------------------------------------------------
# eos import


def _pick_front_vertex(mean: np.ndarray, target_xy: np.ndarray, radius: float) -> int:
    """Vertex nearest to ``target_xy`` (model-space x, y) among those on the front surface:
    of the vertices within ``radius`` in x/y, the one furthest toward the viewer (+z)."""
    d = np.linalg.norm(mean[:, :2] - target_xy, axis=1)
    near = np.flatnonzero(d <= radius)
    if near.size == 0:
        return int(np.argmin(d))
    return int(near[np.argmax(mean[near, 2])])


def semantic_landmarks_from_ibug(mean: np.ndarray, ibug: dict[str, int]) -> dict[str, int]:
    """The semantic landmarks (module docstring) of a model with iBUG-68 names: those with an iBUG
    counterpart take its vertex; cheeks and forehead are placed geometrically from the eye, mouth
    and brow landmarks (cheek: below the outer eye corner, level between eye and mouth corners;
    forehead: on the midline, 60 % of the eye-brow-to-eye gap above the brows — front surface)."""
    out = {name: ibug[num] for name, num in IBUG_SEMANTIC.items() if num in ibug}
    need = ("37", "46", "49", "55", "20", "25", "28")
    if all(k in ibug for k in need):
        p = lambda k: mean[ibug[k]]  # noqa: E731
        eye_outer_dist = np.linalg.norm(p("46") - p("37"))
        radius = 0.06 * eye_outer_dist
        for side, eye, mouth in (("right", "37", "49"), ("left", "46", "55")):
            target = np.array([0.85 * p(eye)[0], 0.5 * (p(eye)[1] + p(mouth)[1])])
            out[f"{side}_cheek"] = _pick_front_vertex(mean, target, radius)
        brow_y = 0.5 * (p("20")[1] + p("25")[1])
        target = np.array([0.5 * (p("20")[0] + p("25")[0]), brow_y + 1.6 * (brow_y - p("28")[1])])
        out["forehead"] = _pick_front_vertex(mean, target, radius)
    return out


def import_eos(
    shape_bin: str | Path,
    blendshapes: str | Path | None = None,
    landmarks: str | Path | None = None,
    contours: str | Path | None = None,
    model_id: str | None = None,
) -> MorphableModel:
    """Build a :class:`MorphableModel` from eos files, in memory.

    shape_bin: eos ``MorphableModel`` binary (e.g. ``sfm_shape_3448.bin``); blendshapes: eos
    blendshapes binary (used when the model file has no expression model of its own); landmarks:
    eos landmark mapping (``ibug_to_sfm.txt``); contours: eos model-contour JSON. Units are the
    model's (the SFM is in mm)."""
    shape_bin = Path(shape_bin)
    eos_model = eos_reader.read_morphable_model(shape_bin)
    shape = eos_model.shape
    V = shape.mean.size // 3
    mean = shape.mean.reshape(V, 3)
    # eos keeps xyzxyz… rows; (3V, S) -> (V, 3, S).
    shape_basis = shape.basis.reshape(V, 3, -1)
    kind, ebasis, estd, enames = "none", np.zeros((V, 3, 0), np.float32), np.zeros(0, np.float32), []
    expression = eos_model.expression
    if blendshapes is not None:
        expression = eos_reader.read_blendshapes(blendshapes)
    if isinstance(expression, list) and expression:
        for b in expression:
            if b.deformation.size != 3 * V:
                raise ModelFormatError(
                    f"blendshape {b.name!r} has {b.deformation.size // 3} vertices, the shape model {V}"
                )
        kind = "blendshapes"
        ebasis = np.stack([b.deformation.reshape(V, 3) for b in expression], axis=2)
        estd = np.ones(len(expression), np.float32)
        enames = [b.name for b in expression]
    elif isinstance(expression, eos_reader.EosPcaModel):
        if expression.mean.size != 3 * V:
            raise ModelFormatError(f"the expression PCA model has {expression.mean.size // 3} vertices, the shape model {V}")
        kind = "pca"
        # An expression PCA mean is an offset; fold it into the neutral mean.
        mean = mean + expression.mean.reshape(V, 3)
        ebasis = expression.basis.reshape(V, 3, -1)
        estd = np.sqrt(np.maximum(expression.eigenvalues, 1e-12)).astype(np.float32)
        enames = [f"expression_pca_{i}" for i in range(estd.size)]

    names: dict[str, int] = {}
    outline_lm_right: list[str] = []
    outline_lm_left: list[str] = []
    if eos_model.landmark_definitions:
        names.update(eos_model.landmark_definitions)
    if landmarks is not None:
        mapping = eos_reader.read_landmark_mapping(landmarks)
        names.update(mapping.mappings)
        outline_lm_right, outline_lm_left = mapping.contour_right, mapping.contour_left
        for k, v in mapping.mappings.items():
            if not 0 <= v < V:
                raise ModelFormatError(f"{landmarks}: landmark {k} maps to vertex {v}, the model has {V}")
        # Semantic names for handles, when the mapping is iBUG-68.
        for sem, vertex in semantic_landmarks_from_ibug(mean, mapping.mappings).items():
            names.setdefault(sem, vertex)
    outline_right = outline_left = np.zeros(0, np.int32)
    if contours is not None:
        outline_right, outline_left = eos_reader.read_model_contour(contours)
    texcoords = eos_model.texcoords.astype(np.float32) if eos_model.texcoords.shape[0] == V else np.zeros((0, 2), np.float32)
    sources = [str(p) for p in (shape_bin, blendshapes, landmarks, contours) if p is not None]
    return MorphableModel(
        model_id=model_id or shape_bin.stem,
        mean=mean,
        triangles=shape.triangles,
        shape_basis=shape_basis,
        shape_std=np.sqrt(np.maximum(shape.eigenvalues, 0)).astype(np.float32),
        expression_kind=kind,
        expression_basis=ebasis,
        expression_std=estd,
        expression_names=enames,
        texcoords=texcoords,
        landmark_names=list(names.keys()),
        landmark_vertices=np.array(list(names.values()), np.int32),
        outline_right=outline_right,
        outline_left=outline_left,
        outline_landmarks_right=outline_lm_right,
        outline_landmarks_left=outline_lm_left,
        units="mm",
        source="eos import: " + ", ".join(Path(s).name for s in sources),
    )


def sfm_files(data_dir: str | Path | None = None) -> dict[str, Path]:
    """Paths of the Surrey Face Model files in the shared data folder (``sfm/``)."""
    base = Path(data_dir) if data_dir is not None else shared_data_dir()
    if base is None:
        raise FileNotFoundError("shared data not found: set FACESCULPT_DATA or place it at ../shared/data")
    sfm = base / "sfm" if (base / "sfm").is_dir() else base
    return {
        "shape_bin": sfm / "sfm_shape_3448.bin",
        "blendshapes": sfm / "expression_blendshapes_3448.bin",
        "landmarks": sfm / "ibug_to_sfm.txt",
        "contours": sfm / "sfm_model_contours.json",
    }


def sfm_from_shared(data_dir: str | Path | None = None) -> MorphableModel:
    """The Surrey Face Model (3448 vertices, 63 shape components, 6 blendshapes, iBUG-68 landmarks,
    outlines) imported straight from the shared data folder."""
    return import_eos(**sfm_files(data_dir), model_id="sfm_shape_3448")


# --------------------------------------------------------------------------------------------
# built-in facemesh


def facemesh_model(neutral: np.ndarray | None = None) -> MorphableModel:
    """The built-in dense model: MediaPipe's 468-vertex face-mesh topology, tessellation from
    ``facesculpt setup`` (``facemesh_triangles.npy``). No PCA bases: in dense mode every vertex is
    observed. The neutral ``mean`` is ``neutral`` (V, 3) when given (e.g. learned from frames), else
    ``facemesh_canonical.npy`` from setup when present, else a placeholder built from the
    tessellation alone (flat, eye-corner distance 90 mm) until the fitter learns a neutral.
    Model space is scaled so the outer-eye-corner distance is :data:`FACEMESH_EYE_CORNER_MM`."""
    triangles = np.load(model_file("facemesh_triangles.npy"), allow_pickle=False)
    source = "facemesh tessellation from facesculpt setup"
    texcoords = np.zeros((0, 2), np.float32)
    if neutral is None:
        try:
            canonical = np.load(model_file("facemesh_canonical.npy"), allow_pickle=False)
            neutral = canonical[:, :3]
            source += "; canonical neutral from setup"
        except FileNotFoundError:
            neutral = None
    if neutral is None:
        neutral = _placeholder_facemesh_neutral(triangles)
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


def _placeholder_facemesh_neutral(triangles: np.ndarray) -> np.ndarray:
    """A stand-in neutral before any frame: a flat 2D layout of the tessellation (Tutte embedding
    with the mesh boundary on an ellipse), bulged toward the viewer in the middle, so the model is
    valid and roughly face-shaped. Replaced by the neutral learned from the first frames."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

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
    A = coo_matrix((np.ones(len(uniq) * 2), (np.r_[uniq[:, 0], uniq[:, 1]], np.r_[uniq[:, 1], uniq[:, 0]])), shape=(V, V)).tocsr()
    deg = np.asarray(A.sum(axis=1)).ravel()
    free = ~fixed
    if free.any() and fixed.any():
        from scipy.sparse import diags

        L = (diags(deg) - A).tocsr()
        rhs = -L[free][:, fixed] @ pos[fixed]
        pos[free] = np.stack([spsolve(L[free][:, free], rhs[:, k]) for k in range(2)], axis=1)
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
