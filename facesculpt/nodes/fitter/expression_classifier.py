"""A learned expression classifier: multinomial logistic regression from a face's expression
parameters (:mod:`.expression`, taken against the person's resting face) and, for a model whose
blendshapes are named for the six basic expressions, its fitted coefficients (likewise taken
against the resting face's) to the seven labels of :mod:`.expression_labels` (the six basic
expressions, then neutral).

The weights are package data (``expression_classifier.npz`` beside this module): per feature
set ("parameters": the named parameters alone, any model; "blendshapes": those and the six
coefficients) the feature names, their mean and scale (the features are standardised), the
weights (7, F) and biases (7,), and a provenance record (JSON: the command that made them, the
training renders, the held-out figures). ``python -m benchmarks.train_expression_classifier``
makes them again. Plain arrays in, arrays out: no sockets, no globals beyond the cached file.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

#: The packaged weights.
WEIGHTS = Path(__file__).with_name("expression_classifier.npz")
#: The feature sets a weights file holds: the expression parameters alone, or those and a
#: model's six expression blendshapes' coefficients.
KINDS: tuple[str, ...] = ("parameters", "blendshapes")


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
    """Write ``classifiers`` (kind -> classifier) and ``provenance`` (JSON-able) to an .npz ``path``."""
    arrays = {"provenance": np.array(json.dumps(provenance, indent=1))}
    for kind, c in classifiers.items():
        arrays.update({f"{kind}.features": np.array(c.features), f"{kind}.mean": c.mean, f"{kind}.scale": c.scale,
                       f"{kind}.weights": c.weights, f"{kind}.bias": c.bias, f"{kind}.labels": np.array(c.labels)})
        if c.pose_bias is not None:
            arrays[f"{kind}.pose_bias"] = c.pose_bias
    np.savez_compressed(path, **arrays)


def load_classifiers(path=None) -> dict[str, ExpressionClassifier]:
    """The classifiers (kind -> :class:`ExpressionClassifier`) in the .npz at ``path`` (None or "":
    the packaged :data:`WEIGHTS`); ValueError in one sentence when the file is missing, unreadable,
    or its arrays do not fit together."""
    return dict(_load(str(path or WEIGHTS)))


@lru_cache(maxsize=4)
def _load(path: str) -> tuple[tuple[str, ExpressionClassifier], ...]:
    try:
        with np.load(path, allow_pickle=False) as z:
            out = []
            for kind in KINDS:
                if f"{kind}.weights" not in z.files:
                    continue
                c = ExpressionClassifier(
                    features=tuple(str(f) for f in z[f"{kind}.features"]), mean=z[f"{kind}.mean"].astype(np.float64),
                    scale=z[f"{kind}.scale"].astype(np.float64), weights=z[f"{kind}.weights"].astype(np.float64),
                    bias=z[f"{kind}.bias"].astype(np.float64), labels=tuple(str(s) for s in z[f"{kind}.labels"]),
                    pose_bias=z[f"{kind}.pose_bias"].astype(np.float64) if f"{kind}.pose_bias" in z.files else None)
                C, F = c.weights.shape
                if not (len(c.features) == F == c.mean.shape[0] == c.scale.shape[0] and c.bias.shape == (C,)
                        and len(c.labels) == C and np.all(c.scale > 0)
                        and (c.pose_bias is None or c.pose_bias.shape == (5, F))):
                    raise ValueError(f"its {kind} arrays do not fit together")
                out.append((kind, c))
    except (OSError, ValueError, KeyError, EOFError) as exc:
        raise ValueError(f"expression labels: cannot use the classifier weights {path}: {exc}") from None
    if not out:
        raise ValueError(f"expression labels: cannot use the classifier weights {path}: it holds none of "
                         f"{', '.join(KINDS)}")
    return tuple(out)


def provenance(path=None) -> dict:
    """The provenance record stored with the weights at ``path`` (None: the packaged ones)."""
    with np.load(str(path or WEIGHTS), allow_pickle=False) as z:
        return json.loads(str(z["provenance"]))
