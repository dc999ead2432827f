"""`facesculpt bench --scenario`: what a user does to the live graph while it is measured.

The window starts as soon as frames come out, so the person's neutral is learned inside it and
the edits are solved on it; then a preset is loaded, the nose tip is dragged, the edits are reset
and loaded again, and the nose is dragged once more: the moments that re-solve the deformation
and could stall the frame path. :meth:`BenchScenario.due` gives the input events whose time has
come (seconds since the window started).
"""

from __future__ import annotations

import time

import numpy as np

from facesculpt.msgs import InputEvent

#: Seconds into the window: preset loads, drags (start, end), the reset before the second load.
LOAD_AT_S = (0.0, 24.0)
RESET_AT_S = 22.0
DRAGS_S = ((8.0, 12.0), (36.0, 40.0))
#: Drag moves per second, and their size: mm per move along the model's (x, y, z).
MOVES_PER_S = 30.0
MOVE_MM = (0.0, -0.15, 0.2)
#: The landmark the drags take hold of (a name every built-in model knows).
DRAG_LANDMARK = "nose_tip"
HANDLE = 7  # a handle of its own, not the mouse's or a joystick's


class BenchScenario:
    """The events of one run (see the module docstring); ``preset_file``: the preset to load."""

    def __init__(self, preset_file: str):
        self.preset_file = str(preset_file)
        self.timeline = sorted(self._plan(), key=lambda event: event[0])
        self.next = 0

    def _plan(self):
        for t in LOAD_AT_S:
            yield t, "command", {"command": "load_preset", "argument": self.preset_file}
        yield RESET_AT_S, "command", {"command": "reset"}
        for start, end in DRAGS_S:
            yield start, "press", {"landmark": DRAG_LANDMARK, "handle": HANDLE}
            for t in np.arange(start + 1.0 / MOVES_PER_S, end, 1.0 / MOVES_PER_S):
                sign = 1.0 if t < 0.5 * (start + end) else -1.0  # out and back
                yield float(t), "move", {"vector": sign * np.asarray(MOVE_MM, np.float32), "handle": HANDLE}
            yield end, "release", {"handle": HANDLE}

    def due(self, elapsed_s: float) -> list[InputEvent]:
        """The events whose time (s since the window started) has come, in order, each once."""
        out = []
        while self.next < len(self.timeline) and self.timeline[self.next][0] <= elapsed_s:
            _, kind, fields = self.timeline[self.next]
            out.append(InputEvent(stamp=time.time_ns(), kind=kind, source="bench", **fields))
            self.next += 1
        return out
