"""The pinch markers: where each pinch is in a frame, from the pinch node's input events, and
the small marker the renderer draws there (the paper's augmented-reality look, its Fig. 7).

:class:`PinchMarkers` keeps the ``press`` / ``drag`` / ``release`` events of one source (the
pinch node's, ``"pinch"``) in the order they arrive; :meth:`PinchMarkers.at` replays those
stamped at or before a frame's stamp, so a frame shows the pinches that were held when it was
captured (an event's stamp is the stamp of the camera frame its hands came from). Each handle
is one pinch: a press or drag puts it at (x, y), a release takes it away.
:func:`draw_pinch_markers` draws a marker per pinch: a white ring with a dark rim around a dot,
sized to the frame. Plain arrays and messages in, no sockets.
"""

from __future__ import annotations

import cv2
import numpy as np

from facesculpt.msgs import InputEvent

SOURCE = "pinch"          # the pinch node's InputEvent.source
MAX_EVENTS = 512          # events kept for replay; older ones are folded into the held state
RING_BGR = (255, 255, 255)
DOT_BGR = (0, 200, 255)   # orange-yellow
RIM_BGR = (0, 0, 0)


class PinchMarkers:
    """The pinches held at each frame, from ``input/events``.

    ``push(event)`` with every InputEvent (others than ``source``'s press / drag / release are
    ignored); ``at(stamp)`` (N, 2) float64 pixels of the pinches held at the frame stamped
    ``stamp`` (ns), in handle order."""

    def __init__(self, source: str = SOURCE, max_events: int = MAX_EVENTS):
        self.source = source
        self.max_events = int(max_events)
        self.events: list[tuple[int, str, int, float, float]] = []   # (stamp, kind, handle, x, y)
        self.base: dict[int, tuple[float, float]] = {}               # held before the kept events

    @staticmethod
    def _apply(held: dict, kind: str, handle: int, x: float, y: float) -> None:
        if kind == "release":
            held.pop(handle, None)
        elif np.isfinite(x) and np.isfinite(y):
            held[handle] = (x, y)

    def push(self, event: InputEvent) -> None:
        if event.source != self.source or event.kind not in ("press", "drag", "release"):
            return
        self.events.append((int(event.stamp), event.kind, int(event.handle), float(event.x), float(event.y)))
        while len(self.events) > self.max_events:
            _, kind, handle, x, y = self.events.pop(0)
            self._apply(self.base, kind, handle, x, y)

    def at(self, stamp: int) -> np.ndarray:
        held = dict(self.base)
        for t, kind, handle, x, y in self.events:
            if t <= stamp:
                self._apply(held, kind, handle, x, y)
        return np.array([held[h] for h in sorted(held)], np.float64).reshape(-1, 2)


def marker_radius(width: int, height: int) -> int:
    """The radius of the marker's ring for a ``width`` x ``height`` frame, px: 1/60 of its smaller
    side, at least 5 (its dark rim reaches 2 px further)."""
    return max(5, int(round(min(width, height) / 60.0)))


def draw_pinch_markers(image: np.ndarray, points) -> np.ndarray:
    """A copy of ``image`` (H, W, 3) uint8 BGR with a marker at each of ``points`` (N, 2) px (the
    same array when N = 0): a white ring with a dark rim around a dot. Non-finite points are
    skipped."""
    p = np.asarray(points, np.float64).reshape(-1, 2)
    p = p[np.isfinite(p).all(axis=1)]
    if not len(p):
        return image
    out = image.copy()
    r = marker_radius(out.shape[1], out.shape[0])
    dot = max(2, r // 3)
    for x, y in np.round(p).astype(int):
        cv2.circle(out, (int(x), int(y)), r, RIM_BGR, 4, cv2.LINE_AA)
        cv2.circle(out, (int(x), int(y)), r, RING_BGR, 2, cv2.LINE_AA)
        cv2.circle(out, (int(x), int(y)), dot + 1, RIM_BGR, -1, cv2.LINE_AA)
        cv2.circle(out, (int(x), int(y)), dot, DOT_BGR, -1, cv2.LINE_AA)
    return out
