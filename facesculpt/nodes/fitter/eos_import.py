"""A :class:`.model.MorphableModel` from eos files (the Surrey Face Model and other eos models),
read with facesculpt's own reader (:mod:`.eos_reader`), and where the shared Surrey Face Model
lives (``load_model("sfm")``).

The import, step by step: the shape PCA model (mean, orthonormal basis, eigenvalues); the
expression model (the eos file's own PCA model or blendshapes, or a separate blendshapes file);
the named landmarks (the model's own definitions, an eos landmark mapping such as
``ibug_to_sfm.txt``, and the semantic names of :mod:`.model` derived from iBUG-68); the outline
vertices (an eos model-contour file); texture coordinates when there is one per vertex.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from facesculpt.nodes.fitter import eos_reader
from facesculpt.nodes.fitter.model import ModelFormatError, MorphableModel
from facesculpt.paths import shared_data_dir

#: iBUG-68 numbers (1-based) of the semantic landmarks that have an iBUG counterpart.
IBUG_SEMANTIC = {
    "nose_tip": "31", "chin": "9", "mouth_right": "49", "mouth_left": "55",
    "right_eye_outer": "37", "right_eye_inner": "40", "left_eye_inner": "43", "left_eye_outer": "46",
    "right_brow": "20", "left_brow": "25", "nose_bridge": "28",
}


def _pick_front_vertex(mean: np.ndarray, target_xy: np.ndarray, radius: float) -> int:
    """Vertex nearest to ``target_xy`` (model-space x, y) among those on the front surface:
    of the vertices within ``radius`` in x/y, the one furthest toward the viewer (+z)."""
    d = np.linalg.norm(mean[:, :2] - target_xy, axis=1)
    near = np.flatnonzero(d <= radius)
    if near.size == 0:
        return int(np.argmin(d))
    return int(near[np.argmax(mean[near, 2])])


def semantic_landmarks_from_ibug(mean: np.ndarray, ibug: dict[str, int]) -> dict[str, int]:
    """The semantic landmarks (:mod:`.model`) of a model with iBUG-68 names: those with an iBUG
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


def _expression_model(expression, V: int) -> tuple[dict, np.ndarray | None]:
    """The expression fields of a model from an eos expression model (a list of blendshapes, an
    :class:`.eos_reader.EosPcaModel` or None) over ``V`` vertices, and the offset (V, 3) that
    belongs in the neutral mean: a PCA model's mean (None for the others)."""
    if isinstance(expression, list) and expression:
        for b in expression:
            if b.deformation.size != 3 * V:
                raise ModelFormatError(
                    f"blendshape {b.name!r} has {b.deformation.size // 3} vertices, the shape model {V}"
                )
        return dict(expression_kind="blendshapes",
                    expression_basis=np.stack([b.deformation.reshape(V, 3) for b in expression], axis=2),
                    expression_std=np.ones(len(expression), np.float32),
                    expression_names=[b.name for b in expression]), None
    if isinstance(expression, eos_reader.EosPcaModel):
        if expression.mean.size != 3 * V:
            raise ModelFormatError(f"the expression PCA model has {expression.mean.size // 3} vertices, the shape model {V}")
        std = np.sqrt(np.maximum(expression.eigenvalues, 1e-12)).astype(np.float32)
        fields = dict(expression_kind="pca", expression_basis=expression.basis.reshape(V, 3, -1),
                      expression_std=std, expression_names=[f"expression_pca_{i}" for i in range(std.size)])
        return fields, expression.mean.reshape(V, 3)
    return dict(expression_kind="none", expression_basis=np.zeros((V, 3, 0), np.float32),
                expression_std=np.zeros(0, np.float32), expression_names=[]), None


def _landmarks(definitions: dict[str, int], landmarks: str | Path | None, mean: np.ndarray) -> dict:
    """The landmark fields of a model: the eos model's own ``definitions`` (name -> vertex), then
    those of the eos landmark mapping file ``landmarks`` with its outline landmark names, then the
    semantic names derived from an iBUG-68 mapping. mean (V, 3) model space."""
    V = len(mean)
    names: dict[str, int] = dict(definitions or {})
    outline_right: list[str] = []
    outline_left: list[str] = []
    if landmarks is not None:
        mapping = eos_reader.read_landmark_mapping(landmarks)
        names.update(mapping.mappings)
        outline_right, outline_left = mapping.contour_right, mapping.contour_left
        for k, v in mapping.mappings.items():
            if not 0 <= v < V:
                raise ModelFormatError(f"{landmarks}: landmark {k} maps to vertex {v}, the model has {V}")
        # Semantic names for handles, when the mapping is iBUG-68.
        for sem, vertex in semantic_landmarks_from_ibug(mean, mapping.mappings).items():
            names.setdefault(sem, vertex)
    return dict(landmark_names=list(names.keys()), landmark_vertices=np.array(list(names.values()), np.int32),
                outline_landmarks_right=outline_right, outline_landmarks_left=outline_left)


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
    expression = eos_reader.read_blendshapes(blendshapes) if blendshapes is not None else eos_model.expression
    fields, offset = _expression_model(expression, V)
    mean = shape.mean.reshape(V, 3)
    if offset is not None:  # an expression PCA mean is an offset: fold it into the neutral mean
        mean = mean + offset
    fields.update(_landmarks(eos_model.landmark_definitions, landmarks, mean))
    if contours is not None:
        fields["outline_right"], fields["outline_left"] = eos_reader.read_model_contour(contours)
    if eos_model.texcoords.shape[0] == V:
        fields["texcoords"] = eos_model.texcoords.astype(np.float32)
    sources = [str(p) for p in (shape_bin, blendshapes, landmarks, contours) if p is not None]
    return MorphableModel(
        model_id=model_id or shape_bin.stem,
        mean=mean,
        triangles=shape.triangles,
        # eos keeps xyzxyz… rows; (3V, S) -> (V, 3, S).
        shape_basis=shape.basis.reshape(V, 3, -1),
        shape_std=np.sqrt(np.maximum(shape.eigenvalues, 0)).astype(np.float32),
        units="mm",
        source="eos import: " + ", ".join(Path(s).name for s in sources),
        **fields,
    )


def sfm_files(data_dir: str | Path | None = None) -> dict[str, Path]:
    """Paths of the Surrey Face Model files in the shared data folder (``sfm/``; default
    :func:`facesculpt.paths.shared_data_dir`), as :func:`import_eos` keywords."""
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
