"""Which frame is rendered with which face state (docs/architecture.md "Stages", 4).

Two policies, both pure bookkeeping (no clocks: time is the messages' stamps, ns):

* ``sync`` — keep the recent frames in a bounded buffer and render a frame when
  the state fitted *on that frame* arrives, so the drawn mesh lies on the face of
  the same image. Frames older than a paired one are dropped (the fitter skipped
  them); a frame that waits longer than ``timeout_ns`` (in stamp time, measured
  against the newest frame) is let through without a face, so a stalled or
  face-less fitter never freezes the output.
* ``latest`` — render every new frame with the newest state (the paper's choice):
  no waiting, the mesh lags the face by the fitter's latency. A state older than
  ``max_age_ns`` relative to the frame is not used (the face is gone or the fitter
  stopped): the frame passes through.

``push_frame`` / ``push_state`` return the pairs ready to render, oldest first, as
:class:`Pair` (state None = pass the frame through). Counters report what was
dropped and why.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

PAIRING_MODES = ("sync", "latest")


@dataclass
class Pair:
    """A frame to render and the state to render it with (None: no face, pass through)."""

    frame: Any
    frame_stamp: int
    state: Any = None
    state_stamp: int | None = None

    @property
    def lag_ns(self) -> int | None:
        """How much older the state's source frame is than the rendered frame (ns)."""
        return None if self.state_stamp is None else self.frame_stamp - self.state_stamp


@dataclass
class FramePairer:
    """Pairs frames with face states by ``mode`` ("sync" or "latest").

    capacity: frames kept while waiting for their state (sync; >= 1).
    timeout_ns: sync: a frame this much older than the newest frame is let through
        without a face. max_age_ns: latest: the oldest state (relative to the frame)
        still drawn.
    """

    mode: str = "latest"
    capacity: int = 30
    timeout_ns: int = 500_000_000
    max_age_ns: int = 500_000_000
    counters: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.mode not in PAIRING_MODES:
            raise ValueError(f"unknown pairing mode {self.mode!r} (known: {', '.join(PAIRING_MODES)})")
        if self.capacity < 1:
            raise ValueError(f"pairing buffer capacity must be >= 1, got {self.capacity}")
        self._frames: OrderedDict[int, Any] = OrderedDict()   # sync: stamp -> frame, in arrival order
        self._early: OrderedDict[int, Any] = OrderedDict()    # sync: states that came before their frame
        self._latest_state: Any = None
        self._latest_state_stamp: int | None = None
        self._newest_frame_stamp: int | None = None

    def _count(self, name: str, n: int = 1) -> None:
        self.counters[name] = self.counters.get(name, 0) + n

    @property
    def buffered(self) -> int:
        """Frames waiting for their state (sync)."""
        return len(self._frames)

    def push_frame(self, stamp: int, frame: Any) -> list[Pair]:
        """A new frame (stamp ns). Returns the pairs now ready to render, oldest first."""
        stamp = int(stamp)
        if self._newest_frame_stamp is not None and stamp <= self._newest_frame_stamp:
            self._count("frame_out_of_order")
            return []
        self._newest_frame_stamp = stamp
        if self.mode == "latest":
            state = self._latest_state
            if state is not None and stamp - self._latest_state_stamp > self.max_age_ns:
                self._count("state_too_old")
                state = None
            if state is None:
                self._count("passed_without_face")
            return [Pair(frame, stamp, state, None if state is None else self._latest_state_stamp)]
        self._frames[stamp] = frame
        if stamp in self._early:  # its state came first
            return self._pair(stamp, self._early.pop(stamp))
        for early in [s for s in self._early if s < stamp]:  # their frames never came
            del self._early[early]
            self._count("state_without_frame")
        ready = []
        while len(self._frames) > self.capacity:
            old_stamp, old_frame = self._frames.popitem(last=False)
            self._count("buffer_overflow")
            ready.append(self._emit(old_stamp, old_frame, None))
        for old_stamp in list(self._frames):
            if stamp - old_stamp <= self.timeout_ns:
                break
            self._count("timed_out")
            ready.append(self._emit(old_stamp, self._frames.pop(old_stamp), None))
        return ready

    def push_state(self, stamp: int, state: Any) -> list[Pair]:
        """A new face state fitted on the frame stamped ``stamp`` (None: no face in it).

        Returns the pairs now ready to render (sync: the state's own frame, or nothing yet
        when that frame has not arrived: frames and states travel on different sockets;
        latest: none, the next frame is rendered with it).
        """
        stamp = int(stamp)
        if self._latest_state_stamp is not None and stamp < self._latest_state_stamp:
            self._count("state_out_of_order")
            return []
        self._latest_state, self._latest_state_stamp = state, stamp
        if self.mode == "latest":
            return []
        if stamp in self._frames:
            return self._pair(stamp, state)
        if self._newest_frame_stamp is None or stamp > self._newest_frame_stamp:
            self._early[stamp] = state  # its frame is still on its way
            while len(self._early) > self.capacity:
                self._early.popitem(last=False)
                self._count("state_without_frame")
            return []
        # Its frame is gone (let through on timeout, or never came); older frames still
        # waiting can never be paired now.
        self._count("state_without_frame")
        skipped = [s for s in self._frames if s < stamp]
        for s in skipped:
            del self._frames[s]
        if skipped:
            self._count("skipped_by_fitter", len(skipped))
        return []

    def _pair(self, stamp: int, state: Any) -> list[Pair]:
        """Render the buffered frame ``stamp`` with ``state``; drop the older waiting frames."""
        for old_stamp in list(self._frames):
            if old_stamp >= stamp:
                break
            del self._frames[old_stamp]
            self._count("skipped_by_fitter")
        return [self._emit(stamp, self._frames.pop(stamp), state)]

    def _emit(self, stamp: int, frame: Any, state: Any) -> Pair:
        if state is None:
            self._count("passed_without_face")
        return Pair(frame, stamp, state, None if state is None else stamp)
