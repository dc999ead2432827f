"""The joystick's pure parts: the line protocol it speaks and the mapping of its samples to
input events. No sockets, no devices, no clocks: callers pass bytes, times (seconds) and
callbacks in, and get plain dicts of ``InputEvent`` fields out
(facesculpt.msgs.InputEvent(**fields) builds the message).

Joystick line protocol (docs/graph/joystick.md)::

    X Y Z BUTTONS\\n        four whitespace-separated decimal integers, one sample per line
                            X, Y, Z: axes in -1000..1000; BUTTONS: bit mask >= 0 (bit 0 = button 0)

Anything else on a line (other counts, non-integers, out of range, over MAX_LINE bytes, bytes
that are not ASCII) makes the line malformed: it is skipped and counted, and the lines around
it are unaffected. Blank lines are ignored. ``\\r\\n`` endings are accepted.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .face_targets import InputError

# -- joystick line protocol -------------------------------------------------------------------

AXIS_MAX = 1000  # axis values are integers in -AXIS_MAX..AXIS_MAX
MAX_LINE = 128  # bytes; a longer line is malformed (a stuck device or the wrong baud rate)
_INT = re.compile(rb"[+-]?[0-9]+\Z")


class ProtocolError(ValueError):
    """A malformed joystick line; the message says why."""


@dataclass(frozen=True)
class Sample:
    """One joystick sample: raw axes (3,) int in -1000..1000 and a button bit mask."""

    axes: tuple[int, int, int]
    buttons: int

    @property
    def normalized(self) -> np.ndarray:
        """Axes as (3,) float32 in -1..1."""
        return np.asarray(self.axes, np.float32) / np.float32(AXIS_MAX)


def parse_line(line: bytes) -> Sample | None:
    """Parse one line (without or with its ``\\n``). None for a blank line; ProtocolError when malformed."""
    if len(line) > MAX_LINE + 2:
        raise ProtocolError(f"line longer than {MAX_LINE} bytes")
    tokens = line.split()
    if not tokens:
        return None
    if len(tokens) != 4:
        raise ProtocolError(f"expected 4 integers 'X Y Z BUTTONS', got {len(tokens)} fields")
    for tok in tokens:
        if not _INT.match(tok):
            raise ProtocolError(f"{tok[:16]!r} is not a decimal integer")
    x, y, z, buttons = (int(t) for t in tokens)
    for name, v in (("X", x), ("Y", y), ("Z", z)):
        if not -AXIS_MAX <= v <= AXIS_MAX:
            raise ProtocolError(f"axis {name} = {v} is outside -{AXIS_MAX}..{AXIS_MAX}")
    if not 0 <= buttons < 2**31:
        raise ProtocolError(f"BUTTONS = {buttons} is not a bit mask in 0..2^31-1")
    return Sample((x, y, z), buttons)


class LineSplitter:
    """Cuts a byte stream into lines. A line that grows past MAX_LINE bytes without a newline is
    dropped up to its newline and reported once as overlong (``None`` in the output)."""

    def __init__(self):
        self.buffer = bytearray()
        self.discarding = False

    def feed(self, data: bytes) -> list[bytes | None]:
        """Complete lines (without ``\\n``) in ``data`` after what came before; None for an overlong one."""
        out: list[bytes | None] = []
        self.buffer += data
        while True:
            nl = self.buffer.find(b"\n")
            if nl < 0:
                if len(self.buffer) > MAX_LINE and not self.discarding:
                    self.discarding = True
                    out.append(None)
                if self.discarding:
                    self.buffer.clear()
                return out
            line = bytes(self.buffer[:nl])
            del self.buffer[: nl + 1]
            if self.discarding:
                self.discarding = False  # the tail of the overlong line, already reported
                continue
            out.append(line if len(line) <= MAX_LINE + 1 else None)

    def reset(self) -> None:
        """Forget a partial line (the device went away mid-line)."""
        self.buffer.clear()
        self.discarding = False


# -- joystick mapping ---------------------------------------------------------------------------


def axis_signs(invert: str) -> np.ndarray:
    """(3,) of +-1 from a string naming the axes to invert, e.g. ``"y"`` or ``"xz"``."""
    bad = set(invert.lower()) - set("xyz, ")
    if bad:
        raise ValueError(f"invert: {invert!r} may only name the axes x, y, z")
    return np.array([-1.0 if a in invert.lower() else 1.0 for a in "xyz"])


@dataclass
class JoystickMapper:
    """Turns joystick samples into input events (dicts of InputEvent fields).

    Per sample: a ``buttons`` event when the mask changed, then the mapped actions on a button's
    rising edge (grab: ``press`` at a landmark; release: ``release``; reset: ``command reset``);
    while it holds a handle, a ``move`` of ``velocity * dt`` (model-space mm), where velocity is
    ``axes_velocity(axes, speed_mm_s, deadzone)`` (mm/s) and dt the time since the previous
    sample, at most ``max_dt_s`` (so a gap in the stream never makes a jump). The pose button
    toggles a pose mode (issue 18): there the axes turn the head instead, a ``pose`` event of
    ``pose_velocity(axes) * dt`` degrees of yaw, pitch and roll (x, y, z axes) per sample, and a
    held handle does not move. Button numbers are bit indices; -1 disables one.
    """

    velocity: Callable[[np.ndarray], np.ndarray]  # (3,) axes in -1..1 -> (3,) model-space mm/s
    signs: np.ndarray = field(default_factory=lambda: np.ones(3))
    grab_button: int = 0
    release_button: int = 1
    reset_button: int = 2
    handle: int = 1
    max_dt_s: float = 0.25
    pose_button: int = -1
    pose_velocity: Callable[[np.ndarray], np.ndarray] | None = None  # (3,) axes -> (3,) yaw, pitch, roll deg/s
    pose_mode: bool = False
    grabbed: bool = False
    buttons: int = 0
    last_t: float | None = None

    def _rose(self, mask: int, button: int) -> bool:
        return button >= 0 and bool(mask >> button & 1) and not bool(self.buttons >> button & 1)

    def step(self, sample: Sample, t: float, grab_target: Callable[[], str]) -> list[dict]:
        """Events for ``sample`` read at time ``t`` (s). ``grab_target()`` names the landmark to
        grab (it may raise InputError: then no press, and the error propagates after the
        other events of this sample are returned through ``InputError.events``)."""
        axes = sample.normalized * self.signs.astype(np.float32)
        events: list[dict] = []
        error: InputError | None = None
        mask = sample.buttons
        if mask != self.buttons:
            events.append(dict(kind="buttons", buttons=mask, axes=axes, handle=self.handle))
            if self._rose(mask, self.reset_button):
                events.append(dict(kind="command", command="reset", handle=self.handle))
                self.grabbed = False
            if self._rose(mask, self.release_button) and self.grabbed:
                events.append(dict(kind="release", handle=self.handle))
                self.grabbed = False
            if self._rose(mask, self.pose_button) and self.pose_velocity is not None:
                self.pose_mode = not self.pose_mode
            if self._rose(mask, self.grab_button) and not self.grabbed:
                try:
                    events.append(dict(kind="press", landmark=grab_target(), handle=self.handle))
                    self.grabbed = True
                except InputError as exc:
                    error = exc
            self.buttons = mask
        dt = 0.0 if self.last_t is None else min(max(t - self.last_t, 0.0), self.max_dt_s)
        self.last_t = t
        if self.pose_mode and dt > 0:
            turn = np.asarray(self.pose_velocity(axes), np.float64) * dt
            if np.any(turn != 0):
                events.append(dict(kind="pose", pose=np.concatenate([turn, np.zeros(3)]).astype(np.float32),
                                   axes=axes, buttons=mask, handle=self.handle))
        elif self.grabbed and dt > 0:
            v = np.asarray(self.velocity(axes), np.float64)
            if np.any(v != 0):
                events.append(dict(kind="move", vector=(v * dt).astype(np.float32), axes=axes,
                                   buttons=mask, handle=self.handle))
        if error is not None:
            error.events = events
            raise error
        return events

    def interrupted(self) -> None:
        """The stream stopped (device lost): the next sample starts a new interval, no jump."""
        self.last_t = None

