"""New views that know their limits (issue 51): the share of a pose edit a frame can take, bounded by
what is known of the surface the turn reveals.

Turning a head shows surface the frame sees badly or not at all (the far cheek, the far temple, the
side of the nose). The renderer takes it from the frame where it is seen, from stored views of the
head (:mod:`.keyframe_views`) where one saw it better; what none of them saw is drawn stretched
from its neighbours, a smear or a mask. Per vertex, the turned view's *frontality* (the cosine
between its normal and its ray to the camera) is what the new view needs of it; the best of the
frame's own frontality and the stored views' qualities is what is known of it. The *unknown share*
of a turn is the area-weighted surface the turned view needs beyond what is known, over the area
the turned view sees. :func:`bounded_share` finds the largest share ``s`` in [0, 1] of the asked
turn whose unknown share stays within ``UNKNOWN_BUDGET`` (interpolated between the shares tried,
so it changes smoothly with the pose), and :class:`PoseLimiter` smooths it over time per face, so
a turn beyond what is known is reduced gradually, never cut to a hard-edged mask.

Plain arrays: vertices (V, 3) camera space (mm in perspective, px scale in orthographic),
triangles (T, 3) int, qualities (V,) in [0, 1].
"""

from __future__ import annotations

import numpy as np

from facesculpt.geometry.pose_offset import PoseOffset, apply_pose_offset
from facesculpt.geometry.vertex_normals import face_normals, vertex_normals

#: The largest share of the turned face's visible area the turn may need beyond what is known.
UNKNOWN_BUDGET = 0.04
#: Frontality from which a view of a surface counts as knowing it (cosine; 0.35: within 70 degrees).
WELL_SEEN = 0.35
#: The shares of the asked turn that are tried (the bound is interpolated between them).
SHARES = np.linspace(0.0, 1.0, 9)
#: Time constant (s) of the bound's smoothing over the frames (it falls faster than it rises:
#: ``FALL_SPEEDUP`` times).
SMOOTHING_S = 0.5
FALL_SPEEDUP = 4.0


def frontality(vertices: np.ndarray, triangles: np.ndarray, perspective: bool, sign: float = 0.0):
    """((V,) float64 cosine between each vertex normal and its ray to the camera, clipped at 0;
    the sign used). ``sign`` 0: chosen so the surface is seen from its front (the mesh as fitted),
    else that sign (a turned copy of it, whose winding is the same)."""
    X = np.asarray(vertices, np.float64)
    n = vertex_normals(X, triangles)
    to_cam = -X / np.maximum(np.linalg.norm(X, axis=1, keepdims=True), 1e-9) if perspective else \
        np.broadcast_to([0.0, 0.0, -1.0], X.shape)
    cos = np.einsum("ij,ij->i", n, to_cam)
    if sign == 0.0:
        sign = -1.0 if cos.sum() < 0 else 1.0
    return np.maximum(sign * cos, 0.0), sign


def vertex_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(V,) float64: a third of the area of each vertex's triangles (the surface it stands for)."""
    tri = np.asarray(triangles, np.int64)
    area = 0.5 * np.linalg.norm(face_normals(vertices, tri), axis=1)
    return np.bincount(tri.ravel(), np.repeat(area, 3), minlength=len(vertices)) / 3.0


def unknown_share(needed: np.ndarray, known: np.ndarray, areas: np.ndarray) -> float:
    """The share (0-1) of the surface a view needs (``needed`` (V,) frontality in it) beyond what is
    ``known`` (V,) of it: sum(area * max(0, needed - known) * badly) / sum(area * needed), where
    ``badly`` = max(0, 1 - known / WELL_SEEN): surface seen at least that frontally is drawn from
    its view, only stretched."""
    total = float(np.dot(areas, needed))
    badly = np.clip(1.0 - known / WELL_SEEN, 0.0, 1.0)
    return float(np.dot(areas, np.maximum(needed - known, 0.0) * badly)) / total if total > 0 else 0.0


def bounded_share(unknown: np.ndarray, shares: np.ndarray = SHARES, budget: float = UNKNOWN_BUDGET) -> float:
    """The largest share of a turn whose unknown share (``unknown`` (S,), one per ``shares`` (S,),
    increasing from 0) stays within ``budget``: linearly interpolated at the first share past it
    (1.0 when none is; 0.0 when even the first is)."""
    over = np.flatnonzero(np.asarray(unknown) > budget)
    if len(over) == 0:
        return 1.0
    i = int(over[0])
    if i == 0:
        return float(shares[0])
    a, b = unknown[i - 1], unknown[i]
    return float(shares[i - 1] + (shares[i] - shares[i - 1]) * (budget - a) / max(b - a, 1e-12))


class PoseLimiter:
    """Per face, the share of its pose edit the known surface allows, smoothed over time.

    :meth:`share`: ``turned(s)`` gives the (V, 3) mesh turned by share ``s`` of the edit; ``known``
    (V,) the best quality any stored view has of each vertex (None: only the frame's own view).
    ``last``: face -> the last share given; ``lowest``: the lowest share given so far (1.0: none
    was reduced); ``reduced``: how many frames were."""

    def __init__(self, budget: float = UNKNOWN_BUDGET, smoothing_s: float = SMOOTHING_S):
        self.budget, self.smoothing_s = float(budget), float(smoothing_s)
        self.last: dict = {}
        self._stamps: dict = {}
        self.lowest, self.reduced = 1.0, 0

    def bound(self, fitted: np.ndarray, triangles: np.ndarray, turned, perspective: bool,
              known: np.ndarray | None = None) -> float:
        """The unsmoothed bound (0-1) for a face ``fitted`` (V, 3) whose turned mesh at share s is
        ``turned(s)``: :func:`bounded_share` of the unknown shares at :data:`SHARES`."""
        now, sign = frontality(fitted, triangles, perspective)
        have = now if known is None else np.maximum(now, np.asarray(known, np.float64))
        areas = vertex_areas(fitted, triangles)
        unknown = [0.0 if s == 0 else unknown_share(frontality(turned(s), triangles, perspective, sign)[0], have, areas)
                   for s in SHARES]
        return bounded_share(np.maximum.accumulate(unknown), SHARES, self.budget)

    def share(self, face, stamp_s: float, fitted: np.ndarray, triangles: np.ndarray, turned, perspective: bool,
              known: np.ndarray | None = None) -> float:
        """The share (0-1) of face ``face``'s pose edit to draw on the frame at ``stamp_s`` (s): the
        :meth:`bound` smoothed over time (exponentially, time constant ``smoothing_s``, falling
        ``FALL_SPEEDUP`` times faster than it rises; the first frame takes it as it is)."""
        target = self.bound(fitted, triangles, turned, perspective, known)
        last, stamp = self.last.get(face), self._stamps.get(face)
        if last is None or stamp is None or self.smoothing_s <= 0:
            value = target
        else:
            tau = self.smoothing_s / (FALL_SPEEDUP if target < last else 1.0)
            value = last + (target - last) * (1.0 - np.exp(-max(stamp_s - stamp, 0.0) / tau))
        self.last[face], self._stamps[face] = float(value), float(stamp_s)
        if value < 0.999:
            self.reduced += 1
            self.lowest = min(self.lowest, float(value))
        return float(value)


def turn_within_limits(limiter: PoseLimiter, face, stamp_s: float, state, deformed: np.ndarray, edit: tuple,
                       triangles: np.ndarray, views: dict | None) -> tuple[np.ndarray, float]:
    """(The (V, 3) ``deformed`` mesh of ``state``'s face (anything with the fitted ``vertices``, R, t,
    scale and projection: a FaceState, a FitResult) turned by the share of its pose ``edit``
    ((PoseOffset, pivot (3,) model mm): :meth:`.pose_edit.PoseEdits.edit`) the ``limiter`` allows,
    that share). ``views``: face -> :class:`.keyframe_views.KeyframeViews` (the compositor's stored
    views; None or empty: only the frame's own view is known)."""
    offset, pivot = edit
    values = np.asarray(offset.as_list(), np.float64)

    def turned(share: float) -> np.ndarray:
        return apply_pose_offset(deformed, state.R, state.t, state.scale, pivot, PoseOffset.from_list(values * share))

    stored = views[face].keyframes if views and face in views else []
    known = np.max([k.quality for k in stored], axis=0) if stored else None
    share = limiter.share(face, stamp_s, np.asarray(state.vertices, np.float64), triangles, turned,
                          state.projection == "perspective", known)
    return turned(share), share
