"""The face states of one frame, gathered: the fitter publishes one FaceState per fitted face
(each saying how many the frame has, ``faces``), or one empty state (``faces`` = 0) for a
frame with none. The renderer pairs a frame with all of them at once.

Pure bookkeeping on stamps (ns), no clocks: a frame's group is complete when ``faces`` states
with that stamp have arrived; a newer stamp completing (or arriving) means the older groups
will never complete (a state was dropped), and they are handed on with what they have.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any


class FaceGroups:
    """Gathers the states of a frame by stamp.

    ``push(stamp, state, faces, face_id)`` returns the groups now ready, oldest first, as
    ``(stamp, states)``: ``states`` a list ordered by face id (empty: no face in that frame).
    capacity: incomplete groups kept at most. ``counters`` says what was cut short.
    """

    def __init__(self, capacity: int = 30):
        self.capacity = max(int(capacity), 1)
        self._open: OrderedDict[int, tuple[int, dict[int, Any]]] = OrderedDict()  # stamp -> (faces, {id: state})
        self.counters: dict[str, int] = {}

    def _count(self, name: str) -> None:
        self.counters[name] = self.counters.get(name, 0) + 1

    def push(self, stamp: int, state: Any, faces: int, face_id: int = 0) -> list[tuple[int, list]]:
        stamp, faces = int(stamp), int(faces)
        ready: list[tuple[int, list]] = []
        # Older groups still open when a newer stamp arrives lost a state on the way.
        for old in [s for s in self._open if s < stamp]:
            self._count("incomplete_group")
            ready.append(self._close(old))
        if faces <= 0:
            ready.append((stamp, []))
            return ready
        expected, got = self._open.get(stamp, (faces, {}))
        got[int(face_id)] = state
        self._open[stamp] = (expected, got)
        if len(got) >= expected:
            ready.append(self._close(stamp))
        while len(self._open) > self.capacity:
            self._count("incomplete_group")
            ready.append(self._close(next(iter(self._open))))
        return ready

    def _close(self, stamp: int) -> tuple[int, list]:
        _, got = self._open.pop(stamp)
        return stamp, [got[k] for k in sorted(got)]
