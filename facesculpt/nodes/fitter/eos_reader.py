"""Readers of the eos model files, written from the published format (no eos at run time).

The eos library (Huber et al., "A Multiresolution 3D Morphable Face Model and Fitting
Framework", VISAPP 2016) stores its models with cereal's *binary* archive: little-endian,
no padding, no field names. The pieces this module decodes:

* ``uint32`` class version, written once before the first ``MorphableModel`` (versions 1-4).
* Eigen matrix: ``int32 rows, int32 cols`` then ``rows*cols`` float32 in column-major order.
* ``std::vector<T>`` / ``std::string`` / ``std::unordered_map``: ``uint64`` element count, then elements.
* ``std::array<int, 3>``: three int32; ``std::array<double, 2>``: two float64.
* optional: ``uint8`` "is empty" flag, then the value when the flag is 0.
* variant: ``int32`` alternative index, then the value.
* ``PcaModel``: mean ``(3V, 1)``, orthonormal basis ``(3V, S)``, eigenvalues ``(S, 1)``, triangles.
* ``MorphableModel`` v1: shape, colour, texcoords; v2 adds the expression model (optional
  variant<PcaModel, Blendshapes>) after colour; v3 adds landmark definitions (optional
  map<string, int>) after that; v4 appends texture triangle indices.
* ``Blendshapes`` file: vector of ``{string name; VectorXf deformation (3V, 1)}``.

Also here: the two text formats shipped with the models — ``ibug_to_sfm.txt`` (TOML subset)
and the model-contour JSON.
"""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


class EosFormatError(ValueError):
    """An eos file does not follow the format this reader understands; the message says where."""


@dataclass
class EosPcaModel:
    """A PCA model as eos stores it. ``mean`` (3V,) float32 xyzxyz…, ``basis`` (3V, S) float32
    orthonormal columns, ``eigenvalues`` (S,) float32 variances, ``triangles`` (T, 3) int32."""

    mean: np.ndarray
    basis: np.ndarray
    eigenvalues: np.ndarray
    triangles: np.ndarray

    @property
    def empty(self) -> bool:
        return self.mean.size == 0


@dataclass
class EosBlendshape:
    """One blendshape: ``deformation`` (3V,) float32 offsets, same layout as a PCA mean."""

    name: str
    deformation: np.ndarray


@dataclass
class EosMorphableModel:
    """Everything an eos ``MorphableModel`` file holds. ``expression`` is None, a list of
    :class:`EosBlendshape`, or an :class:`EosPcaModel`. ``texcoords`` (N, 2) float64 in [0, 1],
    ``texture_triangles`` (T, 3) int32 (empty when texcoords are per-vertex)."""

    version: int
    shape: EosPcaModel
    color: EosPcaModel
    expression: list[EosBlendshape] | EosPcaModel | None = None
    landmark_definitions: dict[str, int] | None = None
    texcoords: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    texture_triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int32))


class _Reader:
    """Sequential little-endian reader over a bytes buffer with bounds checks."""

    def __init__(self, data: bytes, name: str):
        self.data = data
        self.pos = 0
        self.name = name

    def _take(self, n: int, what: str) -> memoryview:
        if n < 0 or self.pos + n > len(self.data):
            raise EosFormatError(
                f"{self.name}: truncated while reading {what} at byte {self.pos} "
                f"(needs {n} bytes, {len(self.data) - self.pos} left)"
            )
        view = memoryview(self.data)[self.pos : self.pos + n]
        self.pos += n
        return view

    def scalar(self, fmt: str, what: str):
        size = struct.calcsize("<" + fmt)
        return struct.unpack("<" + fmt, self._take(size, what))[0]

    def u32(self, what: str) -> int:
        return self.scalar("I", what)

    def i32(self, what: str) -> int:
        return self.scalar("i", what)

    def u64(self, what: str, limit: int = 1 << 31) -> int:
        n = self.scalar("Q", what)
        if n > limit:
            raise EosFormatError(f"{self.name}: implausible count {n} for {what} at byte {self.pos - 8}")
        return n

    def flag(self, what: str) -> bool:
        value = self.scalar("B", what)
        if value not in (0, 1):
            raise EosFormatError(f"{self.name}: {what} flag is {value} at byte {self.pos - 1}, expected 0 or 1")
        return bool(value)

    def array(self, dtype: str, count: int, what: str) -> np.ndarray:
        dt = np.dtype(dtype).newbyteorder("<")
        buf = self._take(count * dt.itemsize, what)
        return np.frombuffer(buf, dtype=dt).astype(dt.newbyteorder("="))

    def string(self, what: str) -> str:
        n = self.u64(what, limit=1 << 20)
        return bytes(self._take(n, what)).decode("utf-8")

    def eigen_matrix(self, what: str) -> np.ndarray:
        rows = self.i32(f"{what} rows")
        cols = self.i32(f"{what} cols")
        if rows < 0 or cols < 0:
            raise EosFormatError(f"{self.name}: {what} has negative size {rows}x{cols}")
        flat = self.array("f4", rows * cols, what)
        # Eigen's default storage is column-major.
        return flat.reshape((cols, rows)).T.copy() if rows * cols else np.zeros((rows, cols), np.float32)

    def eigen_vector(self, what: str) -> np.ndarray:
        mat = self.eigen_matrix(what)
        if mat.size and mat.shape[1] != 1:
            raise EosFormatError(f"{self.name}: {what} should be a column vector, got {mat.shape[0]}x{mat.shape[1]}")
        return mat.reshape(-1)

    def triangles(self, what: str) -> np.ndarray:
        n = self.u64(what)
        return self.array("i4", n * 3, what).reshape(n, 3).astype(np.int32)

    def pca_model(self, what: str) -> EosPcaModel:
        mean = self.eigen_vector(f"{what} mean")
        basis = self.eigen_matrix(f"{what} basis")
        eigenvalues = self.eigen_vector(f"{what} eigenvalues")
        tris = self.triangles(f"{what} triangles")
        if mean.size:
            if mean.size % 3:
                raise EosFormatError(f"{self.name}: {what} mean has {mean.size} values, not a multiple of 3")
            if basis.shape[0] != mean.size:
                raise EosFormatError(
                    f"{self.name}: {what} basis has {basis.shape[0]} rows but the mean has {mean.size}"
                )
            if eigenvalues.size != basis.shape[1]:
                raise EosFormatError(
                    f"{self.name}: {what} has {eigenvalues.size} eigenvalues for {basis.shape[1]} basis columns"
                )
        return EosPcaModel(mean, basis, eigenvalues, tris)

    def blendshapes(self, what: str) -> list[EosBlendshape]:
        n = self.u64(f"{what} count", limit=1 << 16)
        shapes = []
        for i in range(n):
            name = self.string(f"{what}[{i}] name")
            shapes.append(EosBlendshape(name, self.eigen_vector(f"{what}[{i}] deformation")))
        return shapes

    def done(self) -> None:
        if self.pos != len(self.data):
            raise EosFormatError(
                f"{self.name}: {len(self.data) - self.pos} unread bytes after the end of the data "
                f"(byte {self.pos} of {len(self.data)}); not a file of this kind?"
            )


def _read_bytes(path: str | Path) -> tuple[bytes, str]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"eos file not found: {path}")
    return path.read_bytes(), str(path)


def read_morphable_model(path: str | Path) -> EosMorphableModel:
    """Read an eos ``MorphableModel`` binary file (class versions 1-4), e.g. ``sfm_shape_3448.bin``."""
    data, name = _read_bytes(path)
    r = _Reader(data, name)
    version = r.u32("MorphableModel version")
    if version < 1 or version > 4:
        raise EosFormatError(
            f"{name}: MorphableModel version {version} is not supported (1-4 are); "
            "is this an eos MorphableModel file (not blendshapes or a bare PcaModel)?"
        )
    shape = r.pca_model("shape model")
    if shape.empty:
        raise EosFormatError(f"{name}: the shape model is empty")
    color = r.pca_model("colour model")
    expression = None
    landmarks = None
    if version >= 2:
        if not r.flag("expression model nullopt"):
            index = r.i32("expression model variant index")
            if index == 0:
                expression = r.pca_model("expression PCA model")
            elif index == 1:
                expression = r.blendshapes("expression blendshapes")
            else:
                raise EosFormatError(f"{name}: unknown expression model kind {index} (0 = PCA, 1 = blendshapes)")
    if version >= 3:
        if not r.flag("landmark definitions nullopt"):
            n = r.u64("landmark definitions count", limit=1 << 20)
            landmarks = {}
            for i in range(n):
                key = r.string(f"landmark definition {i} name")
                landmarks[key] = r.i32(f"landmark definition {key!r} vertex")
    n_tex = r.u64("texture coordinate count")
    texcoords = r.array("f8", n_tex * 2, "texture coordinates").reshape(n_tex, 2)
    tex_tris = np.zeros((0, 3), np.int32)
    if version >= 4:
        tex_tris = r.triangles("texture triangle indices")
    r.done()
    return EosMorphableModel(version, shape, color, expression, landmarks, texcoords, tex_tris)


def read_blendshapes(path: str | Path) -> list[EosBlendshape]:
    """Read an eos blendshapes file (``std::vector<Blendshape>``), e.g. ``expression_blendshapes_3448.bin``."""
    data, name = _read_bytes(path)
    r = _Reader(data, name)
    shapes = r.blendshapes("blendshapes")
    r.done()
    return shapes


def read_pca_model(path: str | Path) -> EosPcaModel:
    """Read a bare eos ``PcaModel`` file (as written by ``eos.morphablemodel.save_pca_model``)."""
    data, name = _read_bytes(path)
    r = _Reader(data, name)
    model = r.pca_model("PCA model")
    r.done()
    return model


@dataclass
class LandmarkMapping:
    """Contents of an eos landmark-mapping file: ``mappings`` landmark name -> vertex index,
    ``contour_right`` / ``contour_left`` the landmark names on each face outline (in file order)."""

    mappings: dict[str, int]
    contour_right: list[str]
    contour_left: list[str]


_KEY_VALUE = re.compile(r"^\s*(\"[^\"]*\"|[A-Za-z0-9_.\-]+)\s*=\s*(.+?)\s*$")


def read_landmark_mapping(path: str | Path) -> LandmarkMapping:
    """Read an eos landmark mapping (``ibug_to_sfm.txt``: the TOML subset eos writes) —
    ``[landmark_mappings]`` ``name = vertex`` lines and ``[contour_landmarks]`` ``right/left = [..]``."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"landmark mapping not found: {path}")
    text = path.read_text(encoding="utf-8")
    # Strip comments, then join multi-line arrays into one logical line.
    lines = [line.split("#", 1)[0] for line in text.splitlines()]
    logical: list[tuple[int, str]] = []
    pending = ""
    start = 0
    for number, line in enumerate(lines, 1):
        if not pending:
            start = number
        pending += " " + line.strip() if pending else line.strip()
        if pending.count("[") > pending.count("]"):
            continue
        if pending:
            logical.append((start, pending))
        pending = ""
    if pending:
        raise ValueError(f"{path}:{start}: unterminated array")
    section = ""
    mappings: dict[str, int] = {}
    contours: dict[str, list[str]] = {}
    for number, line in logical:
        if re.fullmatch(r"\[[A-Za-z0-9_.\-]+\]", line):
            section = line[1:-1]
            continue
        match = _KEY_VALUE.match(line)
        if not match:
            raise ValueError(f"{path}:{number}: cannot parse {line!r}")
        key, value = match.group(1).strip('"'), match.group(2)
        if section == "landmark_mappings":
            try:
                mappings[key] = int(value.strip('"'))
            except ValueError:
                raise ValueError(f"{path}:{number}: vertex index of landmark {key} is not an integer: {value!r}") from None
        elif section == "contour_landmarks":
            if not (value.startswith("[") and value.endswith("]")):
                raise ValueError(f"{path}:{number}: contour {key} must be an array, got {value!r}")
            items = [item.strip().strip('"') for item in value[1:-1].split(",") if item.strip()]
            contours[key] = items
    if not mappings:
        raise ValueError(f"{path}: no [landmark_mappings] entries")
    return LandmarkMapping(mappings, contours.get("right", []), contours.get("left", []))


def read_model_contour(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read an eos model-contour JSON (``sfm_model_contours.json``); returns the right and left
    outline vertex lists, (N,) int32 each, in file order (top of the face to the chin)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model contour file not found: {path}")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        contour = doc["model_contour"]
        right = np.asarray(contour["right_contour"], dtype=np.int32)
        left = np.asarray(contour["left_contour"], dtype=np.int32)
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(
            f"{path}: not an eos model-contour file (expects model_contour.right_contour/left_contour): {exc}"
        ) from exc
    return right, left
