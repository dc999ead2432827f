"""Several faces in one frame: which faces to fit, and one fitter (one identity) per face.

A selection says which faces of a frame are fitted (and so edited):

* ``"largest"`` — one face, the largest (the landmark detector lists it first); one fitter
  whatever its track id, so the identity it learned survives a lost and re-found track;
* ``"all"`` — every face, each with its own fitter, kept across frames by the detector's
  track id;
* an integer N >= 1 — only face N, faces numbered 1, 2, ... from the left as they are first
  found (the detector's track id N - 1).

:class:`FaceFitters` keeps the fitters and fits a frame's selected faces with
:func:`fit_landmarks` (the fitter node and the in-process pipeline share it).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .fitter import Fitter
from .stage import LandmarksFit, fit_landmarks

#: A selection: "all", "largest" or a face number >= 1.
FaceSelection = str | int


def parse_faces(spec) -> FaceSelection:
    """``"all"``, ``"largest"`` or a face number >= 1 from a string or int; ValueError in one
    sentence otherwise."""
    text = str(spec).strip().lower()
    if text in ("all", "largest"):
        return text
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1 or isinstance(spec, bool):
        raise ValueError(f"faces must be all, largest or a face number from 1 (faces numbered from the left), "
                         f"got {spec!r}")
    return n


def max_faces_for(selection: FaceSelection, limit: int = 8) -> int:
    """How many faces the landmark detector must track for ``selection``."""
    return 1 if selection == "largest" else limit


@dataclass
class FaceFit:
    """One face of a frame: ``key`` the fitter (identity) it was fitted with (0 for "largest",
    else the track id), ``track_id`` the detector's, ``outcome`` the :class:`LandmarksFit`,
    ``index`` its row in the frame's landmarks."""

    key: int
    track_id: int
    outcome: LandmarksFit
    index: int = 0  # the face's row in the frame's landmarks


class FaceFitters:
    """One :class:`Fitter` per selected face, made by ``make()`` when a face is first seen.

    selection: see :func:`parse_faces`. capacity: most fitters kept; the one seen longest ago
    is dropped first (a face gone for good).
    """

    def __init__(self, make: Callable[[], Fitter], selection: FaceSelection = "largest", capacity: int = 16):
        self.make = make
        self.selection = parse_faces(selection)
        self.capacity = max(int(capacity), 1)
        self.fitters: dict[int, Fitter] = {}
        self._seen: dict[int, int] = {}  # key -> frame count when last fitted
        self._frame = 0

    def _key(self, track_id: int) -> int:
        return 0 if self.selection == "largest" else int(track_id)

    def selected(self, track_ids) -> list[int]:
        """Indices (into the frame's faces, in order) of the faces to fit."""
        ids = [int(t) for t in track_ids]
        if not ids:
            return []
        if self.selection == "largest":
            return [0]  # the detector lists the largest face first
        if self.selection == "all":
            return list(range(len(ids)))
        return [i for i, t in enumerate(ids) if t == self.selection - 1]

    @property
    def first(self) -> Fitter | None:
        """The fitter of the lowest face key (the only one for "largest"); None before any face."""
        return self.fitters[min(self.fitters)] if self.fitters else None

    def fitter(self, key: int) -> Fitter:
        """The fitter of face ``key``, made when new (the oldest dropped past ``capacity``)."""
        if key not in self.fitters:
            while len(self.fitters) >= self.capacity:
                oldest = min(self._seen, key=self._seen.get)
                del self.fitters[oldest], self._seen[oldest]
            self.fitters[key] = self.make()
        self._seen[key] = self._frame
        return self.fitters[key]

    def fit(self, points, scores, track_ids, stamp_s: float, min_score: float = 0.5,
            corrections: dict | None = None, image: np.ndarray | None = None, depth=None) -> list[FaceFit]:
        """Fit the selected faces of one frame. points (F, N, 2|3) px, scores (F,), track_ids (F,)
        (None: 0, 1, ...); stamp_s: frame time (s); corrections: face key -> {fit id: (x, y) px}, or
        a function of that face's points this frame ((N, 2|3) px) returning them; image: the frame
        (H, W, 3) uint8, for fitters that refine by appearance; depth: the frame's aligned depth image
        (:class:`.depth_fitting.DepthImage`), the fits refined on it.
        Returns one :class:`FaceFit` per selected face (fitted or not, with the reason), in the
        frame's order; [] when none is selected."""
        self._frame += 1
        points = np.asarray(points)
        if points.ndim != 3 or points.shape[0] == 0:
            return []
        ids = list(range(points.shape[0])) if track_ids is None else [int(t) for t in track_ids]
        if len(ids) != points.shape[0]:
            ids = list(range(points.shape[0]))
        scores = np.asarray(scores, np.float64).ravel()
        out = []
        for i in self.selected(ids):
            key = self._key(ids[i])
            face_scores = scores[i:i + 1] if scores.size == points.shape[0] else scores[:0]
            targets = (corrections or {}).get(key)
            if callable(targets):
                targets = targets(points[i])
            outcome = fit_landmarks(self.fitter(key), points[i:i + 1], face_scores, stamp_s, min_score, targets, image,
                                    depth)
            out.append(FaceFit(key, ids[i], outcome, i))
        return out

    def reset_tracking(self) -> None:
        """Forget when faces were seen (the fitters and their identities stay)."""
        self._seen = {k: 0 for k in self.fitters}
        self._frame = 0
