"""Expressions recognised: the six basic expressions plus neutral, with an intensity, from a
face's expression parameters (:mod:`.expression`) and their motion over a short window (seed 002,
Le 2014, chapter 7).

Three sources of evidence, none learned from the benchmark:

* **The learned classifier** (:mod:`.expression_classifier`; the default for a model with the
  six expression blendshapes, where it beat the rules; the FACS table stays the default for the
  others, where it did not): a logistic regression
  trained on renders of other identities, textures and poses than the benchmark's, from the
  parameters (and a blendshape model's six coefficients) to the seven labels; its scores are
  the labels' probabilities, neutral's among them.
* **The FACS table** (any model). :data:`ACTION_UNITS` measures FACS action units (Ekman &
  Friesen) as linear combinations of the named expression components, each divided by the
  displacement of a clearly marked action (its ``full`` value, %IOD or eye-closure fraction);
  :data:`PROTOTYPES` gives each basic expression its prototype units (EMFACS, as in the CK+
  database's table: happiness 6+12, sadness 1+4+15, surprise 1+2+5+26, fear 1+2+4+5+20+26,
  anger 4+5+7+23, disgust 9+10) and the units that contradict it. An expression's score is
  the mean activation of its units (each clipped to [0, 1]) less half the mean of its
  contradicting ones.
* **A model's named blendshapes** (the Surrey Face Model's six are named for the six basic
  expressions): the fitted coefficient of each, 1 being the blendshape at full strength.
  :func:`blendshape_scores` reads them by name; with both rules ("rules") the scores are their mean.

:class:`ExpressionRecogniser` keeps one face's recent parameters. The first ``baseline_frames``
are the person's resting face (as the fitter's neutral frames): their mean parameters and
coefficients are taken from every later frame's (a fit that explains a resting face partly with
a blendshape, or a resting face with its corners down, is not an expression). The scores are taken on their
mean over ``window_s`` (the static feature), the label is the best score when it beats
neutral's (the classifier's probability; for the rules ``neutral_below``), held until another beats it by ``switch_margin`` (labels do
not flicker between two close scores), and the top score's change over the window gives the
phase: "onset" (rising), "offset" (falling) or "apex" (steady), the seed's dynamic features.
Plain arrays in, a small record out: no sockets, no globals.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from facesculpt.options import option

from .expression_classifier import feature_vector, load_classifiers, pose_terms

#: The labels, in the order of every scores array: the six basic expressions, then neutral.
EXPRESSIONS: tuple[str, ...] = ("anger", "disgust", "fear", "happiness", "sadness", "surprise")
LABELS: tuple[str, ...] = (*EXPRESSIONS, "neutral")
PHASES: tuple[str, ...] = ("onset", "apex", "offset")
#: Where the scores come from (:class:`ExpressionLabelOptions`'s ``source``).
SOURCES: tuple[str, ...] = ("auto", "learned", "rules", "facs", "blendshapes")

_MOUTH_CENTRE_UP = {"upper_lip_raise": -0.5, "jaw_drop": 0.5, "lower_lip_depress": 0.5}


def _both(name: str, weight: float) -> dict[str, float]:
    """The mean of a component's right and left halves, times ``weight``."""
    return {f"{name}_right": weight / 2, f"{name}_left": weight / 2}


#: FACS action unit -> (description, {component: coefficient}, full). The unit's activation is
#: the sum of coefficient x component, divided by ``full`` (the value of a clearly marked action:
#: %IOD for distances, a fraction of the neutral's lid gap for AU5). Lip corners are measured
#: against the mouth's centre (half the jaw's drop carried by the corners is not a smile or a frown).
ACTION_UNITS: dict[str, tuple[str, dict[str, float], float]] = {
    "AU1": ("inner brow raiser", _both("brow_inner_up", 1.0), 6.0),
    "AU2": ("outer brow raiser", _both("brow_outer_up", 1.0), 6.0),
    "AU4": ("brow lowerer", {"brow_lower": 1.0, **_both("brow_inner_up", -0.5)}, 4.0),
    "AU5": ("upper lid raiser", _both("eye_close", -1.0), 0.25),
    "AU6+7": ("cheek raiser, lid tightener", _both("lower_lid_raise", 1.0), 2.5),
    "AU9": ("nose wrinkler", {"nose_wrinkle": 1.0}, 4.0),
    "AU10": ("upper lip raiser", {"upper_lip_raise": 1.0}, 4.0),
    "AU12": ("lip corner puller", {**_both("lip_corner_up", 1.0), **_MOUTH_CENTRE_UP}, 5.0),
    "AU15": ("lip corner depressor", {**_both("lip_corner_up", -1.0),
                                      **{k: -v for k, v in _MOUTH_CENTRE_UP.items()}}, 4.0),
    "AU20": ("lip stretcher", _both("lip_stretch", 1.0), 5.0),
    "AU23": ("lip tightener", _both("lip_stretch", -1.0), 4.0),
    "AU26": ("jaw drop", {"jaw_open": 0.5, "jaw_drop": 0.5}, 10.0),
}

#: Basic expression -> (prototype action units, contradicting action units).
PROTOTYPES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "anger": (("AU4", "AU5", "AU6+7", "AU23"), ("AU1", "AU2", "AU12")),
    "disgust": (("AU9", "AU10"), ("AU1", "AU2", "AU12")),
    "fear": (("AU1", "AU2", "AU4", "AU5", "AU20", "AU26"), ("AU12",)),
    "happiness": (("AU6+7", "AU12"), ("AU4", "AU15")),
    "sadness": (("AU1", "AU4", "AU15"), ("AU2", "AU12")),
    "surprise": (("AU1", "AU2", "AU5", "AU26"), ("AU4",)),
}


@dataclass(frozen=True)
class ExpressionLabelOptions:
    """How expressions are recognised; the fitter node's ``labels_*`` params derive from these."""

    baseline_frames: int = option(30, "expressions recognised: the person's first frames, averaged into the "
                                       "resting face each later frame is compared with (labelled neutral)",
                                   unit="frames", range=(0, 100000))
    window_s: float = option(0.2, "expressions recognised: the parameters are averaged over this window, and the "
                                   "phase (onset, apex, offset) is their change across it, s",
                              range=(0.0, 5.0))
    neutral_below: float = option(0.25, "expressions recognised by the rules (facs, blendshapes): a best score "
                                         "under this is neutral (score 1: every prototype action unit clearly "
                                         "marked)", range=(0.0, 1.0))
    switch_margin: float = option(0.05, "expressions recognised: a new label must beat the shown one's score by "
                                         "this much", range=(0.0, 1.0))
    source: str = option("auto", "expressions recognised from: learned (a classifier trained on renders: the "
                                  "parameters, and a model's six expression blendshapes where it has them), facs "
                                  "(the action-unit table, any model), blendshapes (a model's blendshapes named "
                                  "for the six expressions), rules (facs and blendshapes where the model has "
                                  "them, else facs), or auto: learned for a model with the six blendshapes, "
                                  "else facs",
                          choices=SOURCES)
    weights: str = option("", "expressions recognised: the learned classifier's weights file (.json, as the "
                              "training script writes; an old .npz still loads, with a warning; empty: the "
                              "packaged ones)")


@dataclass(frozen=True)
class ExpressionLabel:
    """One face's recognised expression: ``label`` (one of :data:`LABELS`), ``intensity`` 0..1
    (the label's score; for neutral, 1 minus the best expression's score over ``neutral_below``),
    ``scores`` (7,) float32 in :data:`LABELS` order (neutral's is ``intensity`` when neutral,
    else 0), ``phase`` (one of :data:`PHASES`)."""

    label: str
    intensity: float
    scores: np.ndarray
    phase: str


_UNITS = tuple(ACTION_UNITS)


@lru_cache(maxsize=8)
def _unit_matrix(names: tuple[str, ...]) -> np.ndarray:
    """(U, E) activation of each action unit per unit of each component named in ``names``."""
    index = {n: i for i, n in enumerate(names)}
    out = np.zeros((len(_UNITS), len(names)))
    for u, (_, terms, full) in enumerate(ACTION_UNITS.values()):
        for k, c in terms.items():
            if k in index:
                out[u, index[k]] += c / full
    return out


def _prototype_matrix() -> np.ndarray:
    """(6, U) each expression's score per unit of each (clipped) activation."""
    out = np.zeros((len(EXPRESSIONS), len(_UNITS)))
    for i, e in enumerate(EXPRESSIONS):
        units, against = PROTOTYPES[e]
        for u in units:
            out[i, _UNITS.index(u)] += 1.0 / len(units)
        for u in against:
            out[i, _UNITS.index(u)] -= 0.5 / len(against)
    return out


_SCORES = _prototype_matrix()


def action_units(values: np.ndarray, names) -> dict[str, float]:
    """Activation of each unit of :data:`ACTION_UNITS` (0 = not at all, 1 = clearly marked; may
    exceed 1 or be negative before clipping) from expression parameters ``values`` (E,) named
    ``names``; a component that is missing or NaN counts as 0."""
    a = _unit_matrix(tuple(str(n) for n in names)) @ np.nan_to_num(np.asarray(values, np.float64), nan=0.0)
    return dict(zip(_UNITS, a.tolist()))


def facs_scores(values: np.ndarray, names) -> np.ndarray:
    """(6,) float64 the score of each of :data:`EXPRESSIONS` from the FACS table (module docstring)."""
    a = _unit_matrix(tuple(str(n) for n in names)) @ np.nan_to_num(np.asarray(values, np.float64), nan=0.0)
    return _SCORES @ np.clip(a, 0.0, 1.0)


def has_expression_blendshapes(expression_names) -> bool:
    """True when a model's expression components are blendshapes named for all six basic expressions."""
    return set(EXPRESSIONS) <= {str(n).lower() for n in expression_names}


def blendshape_scores(beta: np.ndarray, expression_names) -> np.ndarray:
    """(6,) float64 the fitted coefficient of the blendshape named for each of :data:`EXPRESSIONS`
    (1: at full strength), clipped to [0, 1]; 0 for one the model does not name."""
    by_name = {str(n).lower(): float(b) for n, b in zip(expression_names, np.asarray(beta, np.float64))}
    return np.clip(np.array([by_name.get(e, 0.0) for e in EXPRESSIONS]), 0.0, 1.0)


class ExpressionRecogniser:
    """One face's expression over time: :meth:`update` with each frame's parameters."""

    def __init__(self, options: ExpressionLabelOptions | None = None, **values):
        self.options = dataclasses.replace(options or ExpressionLabelOptions(), **values)
        if self.options.source not in SOURCES:
            raise ValueError(f"expression labels: source must be one of {', '.join(SOURCES)}, got "
                             f"{self.options.source!r}")
        # the learned classifiers, loaded now: a bad weights file stops the caller at its start
        self.classifiers = load_classifiers(self.options.weights) if self.options.source in ("learned", "auto") else {}
        self.learned = False   # whether the last scores were the classifier's
        self.window: deque[tuple[float, np.ndarray]] = deque()   # (stamp s, scores (7,))
        self.label = "neutral"
        self.seen = 0   # frames taken into the baseline
        self.baseline: tuple[np.ndarray, np.ndarray | None] | None = None   # sums, then means
        self.pose_sum, self.pose_seen = np.zeros(5), 0   # the baseline frames' pose terms (sum), their number

    def reset(self) -> None:
        """Forget the window and the shown label (a new person)."""
        self.window.clear()
        self.label = "neutral"
        self.seen, self.baseline = 0, None
        self.pose_sum, self.pose_seen = np.zeros(5), 0

    def _relative(self, values: np.ndarray, beta) -> tuple[np.ndarray, np.ndarray | None, bool]:
        """``values`` and ``beta`` less the baseline's; True while the baseline is still learned."""
        v = np.nan_to_num(np.asarray(values, np.float64), nan=0.0)
        b = None if beta is None else np.asarray(beta, np.float64)
        n = self.options.baseline_frames
        if self.seen < n:
            if self.baseline is None or self.baseline[0].shape != v.shape:
                self.baseline, self.seen = (np.zeros_like(v), None if b is None else np.zeros_like(b)), 0
            sv, sb = self.baseline
            self.baseline = (sv + v, None if sb is None or b is None or sb.shape != b.shape else sb + b)
            self.seen += 1
            if self.seen == n:
                sv, sb = self.baseline
                self.baseline = (sv / n, None if sb is None else sb / n)
            return v, b, True
        if self.baseline is not None and self.baseline[0].shape == v.shape:
            v = v - self.baseline[0]
            if b is not None and self.baseline[1] is not None and self.baseline[1].shape == b.shape:
                b = b - self.baseline[1]
        return v, b, False

    def scores(self, values: np.ndarray, names, beta=None, expression_names=(), pose_change=None) -> np.ndarray:
        """(7,) one frame's scores in :data:`LABELS` order from the source the options name (module
        docstring); ``beta`` and ``expression_names`` are the fit's expression coefficients and the
        model's names, ``pose_change`` the head pose's terms less the resting face's (the learned
        classifier takes the landmarks' drift with the pose off). The learned classifier's scores
        are its probabilities; the rules' neutral score is ``neutral_below`` (a best expression
        under it is neutral)."""
        blend = beta is not None and has_expression_blendshapes(expression_names)
        src = self.options.source
        if src == "blendshapes" and not blend:
            raise ValueError("expression labels: source=blendshapes needs a model whose blendshapes are named for "
                             f"the six basic expressions ({', '.join(EXPRESSIONS)})")
        self.learned = src == "learned" or (src == "auto" and blend)
        if self.learned:
            c = self.classifiers.get("blendshapes" if blend else "parameters") or self.classifiers.get("parameters")
            if c is None:
                raise ValueError(f"expression labels: the classifier weights {self.options.weights or 'packaged'} "
                                 "hold no weights for the expression parameters alone")
            return c.probabilities(feature_vector(c.features, values, names, beta, expression_names), pose_change)
        if src == "blendshapes":
            six = blendshape_scores(beta, expression_names)
        elif src == "rules" and blend:   # (auto without blendshapes: facs)
            six = (facs_scores(values, names) + blendshape_scores(beta, expression_names)) / 2
        else:
            six = facs_scores(values, names)
        return np.append(six, self.options.neutral_below)

    def update(self, stamp_s: float, values: np.ndarray, names, beta=None, expression_names=(),
               pose=None) -> ExpressionLabel:
        """The label of the frame at ``stamp_s`` (s) with expression parameters ``values`` (E,)
        named ``names`` (and, for a blendshape model, its coefficients ``beta`` (E',) named
        ``expression_names``); ``pose``: the head's (yaw, pitch) in degrees (the fit's), or None."""
        o = self.options
        values, beta, learning = self._relative(values, beta)
        terms = None if pose is None else pose_terms(float(pose[0]), float(pose[1]))
        if learning:
            if terms is not None:
                self.pose_sum, self.pose_seen = self.pose_sum + terms, self.pose_seen + 1
            return ExpressionLabel("neutral", 1.0, np.eye(len(LABELS), dtype=np.float32)[-1], "apex")
        change = None if terms is None or not self.pose_seen else terms - self.pose_sum / self.pose_seen
        self.window.append((float(stamp_s), self.scores(values, names, beta, expression_names, change)))
        while len(self.window) > 1 and self.window[-1][0] - self.window[0][0] > o.window_s + 1e-9:
            self.window.popleft()
        history = np.array([s for _, s in self.window])
        mean = history.mean(axis=0)
        best = int(np.argmax(mean[:6]))
        shown = EXPRESSIONS.index(self.label) if self.label in EXPRESSIONS else None
        if mean[best] < mean[6]:
            self.label = "neutral"
        elif shown is None or mean[shown] < mean[6] or mean[best] > mean[shown] + o.switch_margin:
            self.label = EXPRESSIONS[best]
        scores = np.zeros(len(LABELS), np.float32)
        scores[:6] = np.clip(mean[:6], 0.0, 1.0)
        if self.label == "neutral":
            rule = 1.0 - mean[best] / max(o.neutral_below, 1e-6)
            intensity = float(np.clip(mean[6] if self.learned else rule, 0.0, 1.0))
            scores[6] = intensity
        else:
            intensity = float(scores[EXPRESSIONS.index(self.label)])
        k = EXPRESSIONS.index(self.label) if self.label in EXPRESSIONS else best
        change = history[-1, k] - history[0, k]
        phase = "onset" if change > o.switch_margin else "offset" if change < -o.switch_margin else "apex"
        return ExpressionLabel(self.label, intensity, scores, phase)


def table_rows() -> list[tuple[str, str, str]]:
    """(unit, description, measure) rows of :data:`ACTION_UNITS` for the guide's table."""
    rows = []
    for au, (text, terms, full) in ACTION_UNITS.items():
        measure = " ".join(f"{'+' if c > 0 else '-'} {abs(c):g} {k}" for k, c in terms.items()).lstrip("+ ")
        rows.append((au, text, f"({measure}) / {full:g}"))
    return rows
