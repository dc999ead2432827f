"""Pinch gestures from hand landmarks as input events: pinch to grab, move to drag, bring the
hand closer to push, open to let go. Arrays in, events out; no sockets (the node is
:mod:`.pinch`).

Per tracked hand (``hands/landmarks``' track ids), every frame:

* the pinch ratio is the distance between the thumb tip (joint 4) and the index tip (joint 8),
  in the image plane, over the hand's size (:func:`facesculpt.geometry.hand_regions.hand_size`);
  it **closes** below ``close_ratio`` and **opens** above ``open_ratio`` (hysteresis: between
  the two nothing changes);
* the pinch point is the middle of the two tips, smoothed by a One Euro filter (Casiez et al.
  2012: little smoothing when it moves fast, much when it is nearly still, so a still hand holds
  a still point);
* closing sends ``press`` at the pinch point (the deformer grabs the face under it); while
  closed, moves of at least ``min_move_px`` send ``drag``; the hand's apparent size (smoothed the
  same way) growing by a factor f sends ``depth`` of ``depth_mm * ln f`` mm (+ toward the camera:
  a hand coming closer pulls the point out), in steps of at least ``min_depth_mm``; opening, or
  losing the hand for more than ``max_missing`` frames, sends ``release``.

Each pinching hand holds one of ``max_handles`` handle slots while it pinches (event handle
``first_handle + slot``), so two hands give two handles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from facesculpt.geometry.hand_regions import INDEX_TIP, THUMB_TIP, hand_size
from facesculpt.msgs import InputEvent


@dataclass
class PinchConfig:
    """close_ratio, open_ratio: tip distance / hand size that closes and opens a pinch;
    depth_mm: mm along the view ray per unit of ln(hand size change); min_move_px: the least
    move sent as a drag, px; min_depth_mm: the least depth step sent, mm; min_cutoff_hz, beta:
    the One Euro filter (cutoff at rest, Hz; speed coefficient, 1/px); max_missing: frames a
    pinching hand may be missing before it releases; max_handles, first_handle: handle slots."""

    close_ratio: float = 0.25
    open_ratio: float = 0.40
    depth_mm: float = 60.0
    min_move_px: float = 0.5
    min_depth_mm: float = 0.5
    min_cutoff_hz: float = 1.0
    beta: float = 0.05
    max_missing: int = 3
    max_handles: int = 2
    first_handle: int = 0

    def check(self) -> None:
        if not 0.0 < self.close_ratio < self.open_ratio:
            raise ValueError(f"pinch: close_ratio ({self.close_ratio}) must be above 0 and below open_ratio "
                             f"({self.open_ratio})")


class OneEuro:
    """One Euro filter of a vector (Casiez, Roussel & Vogel 2012); ``__call__(x, t_s)``."""

    def __init__(self, min_cutoff_hz: float, beta: float, d_cutoff_hz: float = 1.0):
        self.min_cutoff, self.beta, self.d_cutoff = float(min_cutoff_hz), float(beta), float(d_cutoff_hz)
        self.x: np.ndarray | None = None
        self.dx: np.ndarray | None = None
        self.t: float | None = None

    @staticmethod
    def _alpha(cutoff: float, dt: float) -> float:
        tau = 1.0 / (2.0 * math.pi * cutoff)
        return 1.0 / (1.0 + tau / dt)

    def __call__(self, x, t_s: float) -> np.ndarray:
        x = np.asarray(x, np.float64)
        if self.x is None or self.t is None or t_s <= self.t:
            self.x, self.dx, self.t = x.copy(), np.zeros_like(x), float(t_s)
            return self.x.copy()
        dt = t_s - self.t
        dx = (x - self.x) / dt
        self.dx = self.dx + self._alpha(self.d_cutoff, dt) * (dx - self.dx)
        cutoff = self.min_cutoff + self.beta * float(np.linalg.norm(self.dx))
        self.x = self.x + self._alpha(cutoff, dt) * (x - self.x)
        self.t = float(t_s)
        return self.x.copy()


@dataclass
class _Hand:
    point: OneEuro
    size: OneEuro
    closed: bool = False
    slot: int = -1
    sent_xy: np.ndarray | None = None
    sent_log_size: float = 0.0
    missing: int = 0
    last_xy: np.ndarray = field(default_factory=lambda: np.zeros(2))


class PinchTracker:
    """Turns hand landmarks frame by frame into press / drag / depth / release events.

    ``update(points, track_ids, stamp_s)``: points (N, 21, >=2) image pixels of the hands of one
    frame, track_ids (N,) int (the same id for the same hand across frames), stamp_s the frame's
    time in seconds; returns the :class:`InputEvent` list of that frame (stamp in ns)."""

    def __init__(self, config: PinchConfig | None = None, source: str = "pinch"):
        self.config = config or PinchConfig()
        self.config.check()
        self.source = source
        self.hands: dict[int, _Hand] = {}

    def _event(self, kind: str, stamp_s: float, hand: _Hand, **fields) -> InputEvent:
        return InputEvent(stamp=int(round(stamp_s * 1e9)), kind=kind, handle=self.config.first_handle + hand.slot,
                          source=self.source, **fields)

    def _free_slot(self) -> int:
        used = {h.slot for h in self.hands.values() if h.closed}
        free = [s for s in range(self.config.max_handles) if s not in used]
        return free[0] if free else -1

    def update(self, points, track_ids, stamp_s: float) -> list[InputEvent]:
        c = self.config
        points = np.asarray(points, np.float64)
        events: list[InputEvent] = []
        seen = set()
        for pts, tid in zip(points.reshape(-1, 21, points.shape[-1]) if points.size else [], track_ids):
            tid = int(tid)
            if not np.isfinite(pts[:, :2]).all():
                continue
            seen.add(tid)
            hand = self.hands.setdefault(tid, _Hand(OneEuro(c.min_cutoff_hz, c.beta), OneEuro(c.min_cutoff_hz, 0.0)))
            hand.missing = 0
            events += self._step(hand, pts[:, :2], stamp_s)
        for tid in list(self.hands):
            if tid in seen:
                continue
            hand = self.hands[tid]
            hand.missing += 1
            if hand.missing > c.max_missing:
                if hand.closed:
                    events.append(self._event("release", stamp_s, hand, x=float(hand.last_xy[0]),
                                              y=float(hand.last_xy[1])))
                del self.hands[tid]
        return events

    def release_all(self, stamp_s: float) -> list[InputEvent]:
        """Release every closed pinch (the node stopping)."""
        events = [self._event("release", stamp_s, h, x=float(h.last_xy[0]), y=float(h.last_xy[1]))
                  for h in self.hands.values() if h.closed]
        self.hands.clear()
        return events

    def _step(self, hand: _Hand, p: np.ndarray, stamp_s: float) -> list[InputEvent]:
        c = self.config
        size = hand_size(p)
        if size <= 1e-6:
            return []
        ratio = float(np.linalg.norm(p[THUMB_TIP] - p[INDEX_TIP])) / size
        xy = hand.point((p[THUMB_TIP] + p[INDEX_TIP]) / 2.0, stamp_s)
        log_size = float(hand.size([math.log(size)], stamp_s)[0])
        hand.last_xy = xy
        if not hand.closed:
            if ratio >= c.close_ratio:
                return []
            slot = self._free_slot()
            if slot < 0:
                return []  # every handle is held by another hand
            # The press lands on the pinch point itself, not on the smoothed way there.
            hand.point.x = None
            xy = hand.last_xy = hand.point((p[THUMB_TIP] + p[INDEX_TIP]) / 2.0, stamp_s)
            hand.closed, hand.slot, hand.sent_xy, hand.sent_log_size = True, slot, xy, log_size
            return [self._event("press", stamp_s, hand, x=float(xy[0]), y=float(xy[1]))]
        if ratio > c.open_ratio:
            hand.closed = False
            event = self._event("release", stamp_s, hand, x=float(xy[0]), y=float(xy[1]))
            hand.slot = -1
            return [event]
        events = []
        if np.linalg.norm(xy - hand.sent_xy) >= c.min_move_px:
            hand.sent_xy = xy
            events.append(self._event("drag", stamp_s, hand, x=float(xy[0]), y=float(xy[1])))
        depth = c.depth_mm * (log_size - hand.sent_log_size)
        if abs(depth) >= c.min_depth_mm:
            hand.sent_log_size = log_size
            events.append(self._event("depth", stamp_s, hand, depth=float(depth)))
        return events
