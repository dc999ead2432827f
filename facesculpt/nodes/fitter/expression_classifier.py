"""A learned expression classifier: multinomial logistic regression from a face's expression
parameters (:mod:`.expression`, taken against the person's resting face) and, for a model whose
blendshapes are named for the six basic expressions, its fitted coefficients (likewise taken
against the resting face's) to the seven labels of :mod:`.expression_labels` (the six basic
expressions, then neutral).

The weights are package data (``expression_classifier.json`` beside this module, float64 values
written so that they read back bit for bit): per feature set ("parameters": the named parameters
alone, any model; "blendshapes": those and the six coefficients) the feature names, their mean and
scale (the features are standardised), the weights (7, F) and biases (7,), the labels, the pose
bias (5, F) or null, and a provenance record (the command that made them, the training renders,
the held-out figures). ``python -m benchmarks.train_expression_classifier``
makes them again. Plain arrays in, arrays out: no sockets, no globals beyond the cached file.
"""

from __future__ import annotations

import json
import warnings
import zipfile
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

#: The packaged weights (JSON: :func:`save_classifiers`).
WEIGHTS = Path(__file__).with_name("expression_classifier.json")
#: The weights files' ``format`` member.
FORMAT = "facesculpt expression classifier"
#: The feature sets a weights file holds: the expression parameters alone, or those and a
#: model's six expression blendshapes' coefficients.
KINDS: tuple[str, ...] = ("parameters", "blendshapes")
#: The fields a feature set's classifier is stored as (``pose_bias`` may be null).
_FIELDS: tuple[str, ...] = ("features", "labels", "mean", "scale", "weights", "bias", "pose_bias")


@dataclass(frozen=True)
class ExpressionClassifier:
    """One feature set's classifier: ``features`` (F,) names (expression parameters by their
    names, blendshape coefficients as ``beta:<expression>``), ``mean`` and ``scale`` (F,) the
    standardisation, ``weights`` (C, F) and ``bias`` (C,) over ``labels`` (C,)."""

    features: tuple[str, ...]
    mean: np.ndarray
    scale: np.ndarray
    weights: np.ndarray
    bias: np.ndarray
    labels: tuple[str, ...]
    pose_bias: np.ndarray | None = None

    def probabilities(self, x: np.ndarray, pose_change: np.ndarray | None = None) -> np.ndarray:
        """(C,) float64 each label's probability for one feature vector ``x`` (F,) (NaN counts as 0),
        or (N, C) for (N, F). ``pose_change``: the head pose's :func:`pose_terms` less the resting
        face's ((5,) or (N, 5)); the features' share that follows the pose (``pose_bias`` (5, F),
        learned on neutral faces: the landmarks' own drift as the head turns) is taken off first."""
        x = np.nan_to_num(np.asarray(x, np.float64), nan=0.0)
        if pose_change is not None and self.pose_bias is not None:
            x = x - np.asarray(pose_change, np.float64) @ self.pose_bias
        return softmax(((x - self.mean) / self.scale) @ self.weights.T + self.bias)


def pose_terms(yaw_deg, pitch_deg) -> np.ndarray:
    """(5,) (or (N, 5) for arrays) the head pose's terms that the features' drift is fitted on:
    yaw, pitch, yaw², pitch², yaw x pitch, with the angles in units of 10 degrees."""
    y, p = np.asarray(yaw_deg, np.float64) / 10.0, np.asarray(pitch_deg, np.float64) / 10.0
    return np.stack([y, p, y * y, p * p, y * p], axis=-1)


def fit_pose_bias(pose_change: np.ndarray, feature_change: np.ndarray, l2: float = 1e-2) -> np.ndarray:
    """(5, F) the ridge least-squares map from neutral faces' ``pose_change`` (N, 5) (:func:`pose_terms`
    less the resting face's) to their ``feature_change`` (N, F) (the features less the resting face's)."""
    A = np.asarray(pose_change, np.float64)
    return np.linalg.solve(A.T @ A + l2 * len(A) * np.eye(A.shape[1]), A.T @ np.asarray(feature_change, np.float64))


def softmax(logits: np.ndarray) -> np.ndarray:
    """Softmax over the last axis of ``logits``."""
    e = np.exp(logits - logits.max(axis=-1, keepdims=True))
    return e / e.sum(axis=-1, keepdims=True)


def feature_vector(features: tuple[str, ...], values: np.ndarray, names, beta=None, expression_names=()) -> np.ndarray:
    """(F,) float64 the ``features`` named (see :class:`ExpressionClassifier`) from expression
    parameters ``values`` (E,) named ``names`` and coefficients ``beta`` named ``expression_names``
    (both already taken against the resting face); a feature the inputs lack is 0."""
    by_name = {str(n): float(v) for n, v in zip(names, np.asarray(values, np.float64))}
    if beta is not None:
        by_name.update({f"beta:{str(n).lower()}": float(b)
                        for n, b in zip(expression_names, np.asarray(beta, np.float64))})
    return np.nan_to_num(np.array([by_name.get(f, 0.0) for f in features]), nan=0.0)


def fit_logistic(X: np.ndarray, y: np.ndarray, classes: int, l2: float = 1e-2,
                 iterations: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Multinomial logistic regression by Newton's method: weights (C, F) and biases (C,) that
    minimise the mean cross-entropy of standardised features ``X`` (N, F) against labels ``y``
    (N,) int in [0, ``classes``) plus ``l2`` / 2 times the weights' squared norm (not the biases')."""
    X = np.asarray(X, np.float64)
    N, F = X.shape
    A = np.hstack([X, np.ones((N, 1))])
    Y = np.eye(classes)[np.asarray(y, np.int64)]
    theta = np.zeros((classes, F + 1))
    reg = np.full(F + 1, l2)
    reg[-1] = 1e-8
    for _ in range(iterations):
        P = softmax(A @ theta.T)
        grad = ((P - Y).T @ A) / N + theta * reg
        H = np.zeros((classes, F + 1, classes, F + 1))
        for k in range(classes):
            for m in range(k, classes):
                w = P[:, k] * ((k == m) - P[:, m])
                H[k, :, m, :] = H[m, :, k, :] = (A * w[:, None]).T @ A / N
        H = H.reshape(classes * (F + 1), -1) + np.diag(np.tile(reg, classes))
        step = np.linalg.lstsq(H, grad.ravel(), rcond=None)[0].reshape(theta.shape)
        theta -= step
        if np.abs(step).max() < 1e-7:
            break
    return theta[:, :F], theta[:, F]


def save_classifiers(path, classifiers: dict[str, ExpressionClassifier], provenance: dict) -> None:
    """Write ``classifiers`` (kind -> classifier) and ``provenance`` (JSON-able) to a JSON ``path``
    (:data:`WEIGHTS`' layout); the float64 values are written as Python's shortest repr, which reads
    back bit for bit. ValueError for a value JSON cannot hold (NaN, infinity)."""
    doc = {"format": FORMAT, "classifiers": {}, "provenance": provenance}
    for kind, c in classifiers.items():
        doc["classifiers"][kind] = {
            "features": list(c.features), "labels": list(c.labels), "mean": c.mean.tolist(), "scale": c.scale.tolist(),
            "weights": c.weights.tolist(), "bias": c.bias.tolist(),
            "pose_bias": None if c.pose_bias is None else c.pose_bias.tolist()}
    Path(path).write_text(_json_text(doc) + "\n", encoding="utf-8")


def load_classifiers(path=None) -> dict[str, ExpressionClassifier]:
    """The classifiers (kind -> :class:`ExpressionClassifier`) in the weights file at ``path``
    (None or "": the packaged :data:`WEIGHTS`); ValueError in one sentence when the file is missing,
    unreadable, or its arrays do not fit together. An .npz written by the training script before the
    weights were JSON still loads, with a DeprecationWarning (once per file) saying how to convert it."""
    return dict(_load(str(path or WEIGHTS))[0])


def provenance(path=None) -> dict:
    """The provenance record stored with the weights at ``path`` (None: the packaged ones; {} where
    the file has none); ValueError in one sentence as :func:`load_classifiers`."""
    return json.loads(_load(str(path or WEIGHTS))[1])


def convert_npz_weights(path, out=None) -> Path:
    """Write the old .npz weights file at ``path`` as JSON to ``out`` (default: beside it, suffix
    .json; its provenance says it was converted) and return that path; FileExistsError rather than
    overwrite a file."""
    out = Path(out) if out else Path(path).with_suffix(".json")
    if out.exists():
        raise FileExistsError(f"expression labels: {out} exists already; not overwritten")
    doc = _read_npz(str(path))
    classifiers = {kind: _classifier(kind, fields) for kind, fields in doc["classifiers"].items()}
    record = {**doc["provenance"], "converted": f"from {Path(path).name} to JSON (convert_npz_weights), the "
                                                f"values bit for bit"}
    save_classifiers(out, classifiers, record)
    return out


@lru_cache(maxsize=4)
def _load(path: str) -> tuple[tuple[tuple[str, ExpressionClassifier], ...], str]:
    """The classifiers at ``path`` in :data:`KINDS` order and the provenance as JSON text (cached)."""
    try:
        if _is_npz(path):
            doc = _read_npz(path)
            warnings.warn(f"expression labels: the weights file {path} is an .npz, which the next release will "
                          f"not read; convert it to JSON once with: python -c \"from facesculpt.nodes.fitter."
                          f"expression_classifier import convert_npz_weights; convert_npz_weights('{path}')\"",
                          DeprecationWarning, stacklevel=3)
        else:
            doc = _read_json(path)
        out = tuple((kind, _classifier(kind, doc["classifiers"][kind])) for kind in KINDS
                    if kind in doc["classifiers"])
        record = json.dumps(doc["provenance"])
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"expression labels: cannot use the classifier weights {path}: {exc}") from None
    if not out:
        raise ValueError(f"expression labels: cannot use the classifier weights {path}: it holds none of "
                         f"{', '.join(KINDS)}")
    return out, record


def _read_json(path: str) -> dict:
    """The document of a JSON weights file: {"classifiers": {kind: {field: value}}, "provenance": dict}."""
    with open(path, encoding="utf-8") as f:
        try:
            doc = json.load(f)
        except json.JSONDecodeError as exc:
            raise ValueError(f"it is neither JSON ({exc}) nor an old .npz") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or not isinstance(doc.get("classifiers"), dict):
        raise ValueError(f"it is not a {FORMAT} file (JSON with \"format\": \"{FORMAT}\" and \"classifiers\")")
    if not all(isinstance(fields, dict) for fields in doc["classifiers"].values()):
        raise ValueError("each of its classifiers must be an object of named fields")
    return {"classifiers": doc["classifiers"], "provenance": doc.get("provenance") or {}}


def _is_npz(path: str) -> bool:
    with open(path, "rb") as f:
        return f.read(4) == b"PK\x03\x04"


def _read_npz(path: str) -> dict:
    """The document (as :func:`_read_json`'s) of an .npz the training script wrote before the weights
    were JSON: arrays named ``<kind>.<field>`` and a JSON string ``provenance``."""
    with np.load(path, allow_pickle=False) as z:
        classifiers = {kind: {field: z[f"{kind}.{field}"] for field in _FIELDS if f"{kind}.{field}" in z.files}
                       for kind in KINDS if f"{kind}.weights" in z.files}
        record = json.loads(str(z["provenance"])) if "provenance" in z.files else {}
    return {"classifiers": classifiers, "provenance": record}


def _classifier(kind: str, fields: dict) -> ExpressionClassifier:
    """One feature set's classifier from its ``fields`` (lists or arrays; ``pose_bias`` may be
    absent or None); ValueError when one is missing or they do not fit together."""
    missing = [f for f in _FIELDS if f not in fields and f != "pose_bias"]
    if missing:
        raise ValueError(f"its {kind} classifier lacks {', '.join(missing)}")
    pose_bias = fields.get("pose_bias")
    c = ExpressionClassifier(
        features=tuple(str(f) for f in fields["features"]), mean=np.asarray(fields["mean"], np.float64),
        scale=np.asarray(fields["scale"], np.float64), weights=np.asarray(fields["weights"], np.float64),
        bias=np.asarray(fields["bias"], np.float64), labels=tuple(str(s) for s in fields["labels"]),
        pose_bias=None if pose_bias is None else np.asarray(pose_bias, np.float64))
    C, F = c.weights.shape if c.weights.ndim == 2 else (-1, -1)
    arrays = (c.mean, c.scale, c.weights, c.bias) + (() if c.pose_bias is None else (c.pose_bias,))
    if not (len(c.features) == F and c.mean.shape == c.scale.shape == (F,) and c.bias.shape == (C,)
            and len(c.labels) == C and np.all(c.scale > 0) and all(np.all(np.isfinite(a)) for a in arrays)
            and (c.pose_bias is None or c.pose_bias.shape == (5, F))):
        raise ValueError(f"its {kind} arrays do not fit together")
    return c


def _json_text(value, indent: int = 0) -> str:
    """``value`` as JSON text: an object's members one a line, a list of plain values on one line."""
    pad, end = " " * (indent + 1), " " * indent
    if isinstance(value, dict) and value:
        members = [f"{pad}{json.dumps(str(k))}: {_json_text(v, indent + 1)}" for k, v in value.items()]
        return "{\n" + ",\n".join(members) + "\n" + end + "}"
    if isinstance(value, (list, tuple)) and any(isinstance(v, (dict, list, tuple)) for v in value):
        return "[\n" + ",\n".join(pad + _json_text(v, indent + 1) for v in value) + "\n" + end + "]"
    return json.dumps(value, allow_nan=False)
