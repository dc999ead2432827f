"""The input nodes' pure parts: the joystick line protocol, the joystick's mapping of samples to
input events, and the gesture-script format and player (time -> events). No sockets, no
devices, no clocks: callers pass bytes, times (seconds) and callbacks in, and get plain
dicts of ``InputEvent`` fields out (facesculpt.msgs.InputEvent(**fields) builds the message).

Joystick line protocol (README "Input events")::

    X Y Z BUTTONS\\n        four whitespace-separated decimal integers, one sample per line
                            X, Y, Z: axes in -1000..1000; BUTTONS: bit mask >= 0 (bit 0 = button 0)

Anything else on a line (other counts, non-integers, out of range, over MAX_LINE bytes, bytes
that are not ASCII) makes the line malformed: it is skipped and counted, and the lines around
it are unaffected. Blank lines are ignored. ``\\r\\n`` endings are accepted.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

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


class InputError(ValueError):
    """An input that cannot be turned into events (no face to grab, unknown landmark, ...)."""


def roi_centre(projected: np.ndarray) -> np.ndarray:
    """Centre (2,) pixels of the bounding box of the projected fitted face ``projected`` (V, 2)."""
    p = np.asarray(projected, np.float64)
    p = p[np.all(np.isfinite(p), axis=1)]
    if p.size == 0:
        raise InputError("the fitted face has no projected vertices")
    return (p.min(axis=0) + p.max(axis=0)) / 2.0


def nearest_landmark(projected: np.ndarray, names: list[str], vertices: np.ndarray, point) -> str:
    """The landmark whose projection (pixels, from ``projected`` (V, 2)) is nearest ``point`` (x, y).

    ``names[i]`` is the landmark at vertex ``vertices[i]``. Among names of one vertex (an iBUG
    number and a semantic name) the semantic one wins."""
    idx = np.asarray(vertices, np.int64)
    if len(names) == 0 or idx.size != len(names):
        raise InputError("the face model has no landmark names")
    ok = (idx >= 0) & (idx < len(projected))
    if not np.any(ok):
        raise InputError("the face model's landmark vertices are not in the fitted face")
    d = np.linalg.norm(np.asarray(projected, np.float64)[np.where(ok, idx, 0)] - np.asarray(point, np.float64), axis=1)
    d = np.where(ok & np.isfinite(d), d, np.inf)
    best = min(range(len(names)), key=lambda i: (round(float(d[i]), 6), names[i].isdigit(), i))
    return names[best]


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
    sample, at most ``max_dt_s`` (so a gap in the stream never makes a jump). Button numbers
    are bit indices; -1 disables one.
    """

    velocity: Callable[[np.ndarray], np.ndarray]  # (3,) axes in -1..1 -> (3,) model-space mm/s
    signs: np.ndarray = field(default_factory=lambda: np.ones(3))
    grab_button: int = 0
    release_button: int = 1
    reset_button: int = 2
    handle: int = 1
    max_dt_s: float = 0.25
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
            if self._rose(mask, self.grab_button) and not self.grabbed:
                try:
                    events.append(dict(kind="press", landmark=grab_target(), handle=self.handle))
                    self.grabbed = True
                except InputError as exc:
                    error = exc
            self.buttons = mask
        dt = 0.0 if self.last_t is None else min(max(t - self.last_t, 0.0), self.max_dt_s)
        self.last_t = t
        if self.grabbed and dt > 0:
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


# -- gesture scripts ------------------------------------------------------------------------------


class ScriptError(ValueError):
    """A gesture script that cannot be read or played; the message names the file and line."""


@dataclass(frozen=True)
class Action:
    """One timed action of a compiled script: ``t`` seconds from the start."""

    t: float
    kind: str  # press | drag_px | move | depth | release | command
    handle: int
    line: int  # line of the step in the script (for error messages)
    landmark: str = ""
    xy: tuple = ()  # press: pixel (x, y)
    step_id: int = -1  # drag_px: which drag step (its start pixel is taken at its first action)
    frac: float = 0.0  # drag_px: fraction of the drag done after this action
    total: tuple = ()  # drag_px: (dx, dy) px of the whole drag
    vector: tuple = ()  # move: model-space mm of this action
    depth: float = 0.0  # depth: mm of this action
    command: str = ""
    argument: str = ""


@dataclass
class GestureScript:
    """A compiled script: actions sorted by time, its duration (s), and where it came from."""

    actions: list[Action]
    duration: float
    source: str
    name: str = ""
    rate_hz: float = 30.0

    def landmarks(self) -> dict[str, int]:
        """Landmark names pressed, each with the line of its first use."""
        out: dict[str, int] = {}
        for a in self.actions:
            if a.landmark and a.landmark not in out:
                out[a.landmark] = a.line
        return out


STEP_KINDS = ("press", "drag", "depth", "release", "wait", "load_preset", "save_preset", "command", "parallel")
_SCRIPT_KEYS = {"name", "rate_hz", "steps"}


def _line_of(node) -> int:
    return node.start_mark.line + 1 if node is not None else 0


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """`` line L, column C: not valid YAML (...)`` — at the construct that is open when the
    parser gives up (an unclosed bracket's line), else where it gave up."""
    mark, problem = getattr(exc, "problem_mark", None), getattr(exc, "problem", None)
    context, context_mark = getattr(exc, "context", None), getattr(exc, "context_mark", None)
    if mark is None:
        return f": not valid YAML ({str(exc).splitlines()[0]})"
    if context and context_mark is not None and context_mark.line != mark.line:
        return (f" line {context_mark.line + 1}, column {context_mark.column + 1}: not valid YAML ({context}: "
                f"{problem} at line {mark.line + 1}, column {mark.column + 1})")
    return f" line {mark.line + 1}, column {mark.column + 1}: not valid YAML ({problem})"


def load_script(path: str | Path, default_handle: int = 2) -> GestureScript:
    """Read and compile a gesture script file (preset paths relative to the file's folder)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ScriptError(f"gesture script {path} not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ScriptError(f"cannot read gesture script {path}: {exc}") from None
    return parse_script(text, source=str(path), base_dir=path.parent, default_handle=default_handle)


def parse_script(text: str, source: str = "<script>", base_dir: str | Path | None = None,
                 default_handle: int = 2) -> GestureScript:
    """Compile a gesture script (YAML text, format in README "Input events") into timed actions.

    Raises ScriptError with ``"SOURCE line N: ..."`` for a YAML syntax error or a step that does
    not fit the format."""
    try:
        root = yaml.compose(text)
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ScriptError(f"{source}{_yaml_problem(exc)}") from None
    if isinstance(doc, list):
        doc, steps_node = {"steps": doc}, root
    elif isinstance(doc, dict):
        steps_node = next((v for k, v in root.value if k.value == "steps"), None)
    if not isinstance(doc, dict):
        raise ScriptError(f"{source}: a gesture script is a mapping with 'steps:' (a list of steps)")
    unknown = sorted(set(map(str, doc)) - _SCRIPT_KEYS)
    if unknown:
        raise ScriptError(f"{source}: unknown key(s) {', '.join(unknown)} (known: name, rate_hz, steps)")
    steps = doc.get("steps")
    if not isinstance(steps, list) or not steps or not isinstance(steps_node, yaml.SequenceNode):
        raise ScriptError(f"{source}: 'steps:' must be a non-empty list of steps")
    rate = doc.get("rate_hz", 30.0)
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 < rate <= 1000:
        raise ScriptError(f"{source}: rate_hz must be a number in (0, 1000], got {rate!r}")
    compiler = _Compiler(source, Path(base_dir) if base_dir is not None else None, float(rate), default_handle)
    end = compiler.sequence(steps, steps_node.value, 0.0)
    actions = sorted(compiler.actions, key=lambda a: a.t)  # stable: same-time actions keep script order
    return GestureScript(actions, end, source, str(doc.get("name", "")), float(rate))


class _Compiler:
    def __init__(self, source: str, base_dir: Path | None, rate_hz: float, default_handle: int):
        self.source = source
        self.base_dir = base_dir
        self.rate_hz = rate_hz
        self.default_handle = default_handle
        self.actions: list[Action] = []
        self.steps = 0
        self.held: set[int] = set()  # handles pressed and not released, in script order

    def fail(self, line: int, what: str):
        raise ScriptError(f"{self.source} line {line}: {what}")

    def sequence(self, steps: list, nodes: list, t: float) -> float:
        for step, node in zip(steps, nodes):
            t = self.step(step, node, t)
        return t

    # -- field readers --------------------------------------------------------------------------
    def number(self, line, kind, value, what, lo=-math.inf, hi=math.inf) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            self.fail(line, f"{kind}: {what} must be a number, got {value!r}")
        if not lo <= value <= hi:
            self.fail(line, f"{kind}: {what} must be in [{lo}, {hi}], got {value!r}")
        return float(value)

    def vector(self, line, kind, value, n, what) -> tuple:
        if not isinstance(value, (list, tuple)) or len(value) != n:
            self.fail(line, f"{kind}: {what} must be a list of {n} numbers, got {value!r}")
        return tuple(self.number(line, kind, v, what) for v in value)

    def fields(self, line, kind, arg, allowed: set, shorthand: str | None = None) -> dict:
        if arg is None:
            return {}
        if not isinstance(arg, dict):
            if shorthand is None:
                self.fail(line, f"{kind}: expected a mapping of {', '.join(sorted(allowed))}")
            return {shorthand: arg}
        unknown = sorted(set(map(str, arg)) - allowed)
        if unknown:
            self.fail(line, f"{kind}: unknown field(s) {', '.join(unknown)} (known: {', '.join(sorted(allowed))})")
        return arg

    def handle(self, line, kind, f) -> int:
        h = f.get("handle", self.default_handle)
        if isinstance(h, bool) or not isinstance(h, int):
            self.fail(line, f"{kind}: handle must be an integer, got {h!r}")
        return h

    @staticmethod
    def at(t: float, duration: float, k: int, n: int) -> float:
        """Time of tick k of n; the last one is exactly the step's end (so ordering holds)."""
        return t + duration if k == n else t + duration * k / n

    def held_handle(self, line, kind, f) -> int:
        h = self.handle(line, kind, f)
        if h not in self.held:
            self.fail(line, f"{kind}: handle {h} is not pressed here (add a press step before it)")
        return h

    def ticks(self, line, kind, f) -> tuple[float, int]:
        duration = self.number(line, kind, f.get("duration_s", 0.0), "duration_s", 0.0, 3600.0)
        return duration, max(1, math.ceil(duration * self.rate_hz - 1e-9))

    def path(self, line, kind, value) -> str:
        if not isinstance(value, str) or not value.strip():
            self.fail(line, f"{kind}: needs a file path")
        p = Path(value).expanduser()
        if not p.is_absolute() and self.base_dir is not None:
            p = (self.base_dir / p).resolve()
        return str(p)

    # -- steps ------------------------------------------------------------------------------------
    def step(self, step, node, t: float) -> float:
        line = _line_of(node)
        if isinstance(step, str):
            kind, arg = step, None
        elif isinstance(step, dict) and len(step) == 1:
            kind, arg = next(iter(step.items()))
        else:
            self.fail(line, f"a step is one of {', '.join(STEP_KINDS)} (e.g. '- press: nose_tip'), got {step!r}")
        if kind not in STEP_KINDS:
            self.fail(line, f"unknown step {kind!r} (known: {', '.join(STEP_KINDS)})")
        self.steps += 1
        add = self.actions.append
        if kind == "press":
            f = self.fields(line, kind, arg, {"landmark", "pixel", "handle"}, shorthand="landmark")
            h = self.handle(line, kind, f)
            self.held.add(h)
            if ("landmark" in f) == ("pixel" in f):
                self.fail(line, "press: give exactly one of landmark (a name) or pixel ([x, y])")
            if "landmark" in f:
                name = f["landmark"]
                if not isinstance(name, (str, int)) or isinstance(name, bool) or not str(name).strip():
                    self.fail(line, f"press: landmark must be a name, got {name!r}")
                add(Action(t, "press", h, line, landmark=str(name).strip()))
            else:
                add(Action(t, "press", h, line, xy=self.vector(line, kind, f["pixel"], 2, "pixel")))
            return t
        if kind == "drag":
            f = self.fields(line, kind, arg, {"mm", "px", "duration_s", "handle"})
            h = self.held_handle(line, kind, f)
            if ("mm" in f) == ("px" in f):
                self.fail(line, "drag: give exactly one of mm ([x, y, z], model space) or px ([dx, dy], image)")
            duration, n = self.ticks(line, kind, f)
            if "mm" in f:
                total = np.array(self.vector(line, kind, f["mm"], 3, "mm"))
                for k in range(1, n + 1):  # increments that add up to the total exactly
                    inc = total * (k / n) - total * ((k - 1) / n)
                    add(Action(self.at(t, duration, k, n), "move", h, line, vector=tuple(inc.tolist())))
            else:
                total = self.vector(line, kind, f["px"], 2, "px")
                sid = len(self.actions)
                for k in range(1, n + 1):
                    add(Action(self.at(t, duration, k, n), "drag_px", h, line, step_id=sid, frac=k / n, total=total))
            return t + duration
        if kind == "depth":
            f = self.fields(line, kind, arg, {"mm", "duration_s", "handle"}, shorthand="mm")
            h = self.held_handle(line, kind, f)
            if "mm" not in f:
                self.fail(line, "depth: needs mm (+ toward the camera)")
            total = self.number(line, kind, f["mm"], "mm")
            duration, n = self.ticks(line, kind, f)
            for k in range(1, n + 1):
                add(Action(self.at(t, duration, k, n), "depth", h, line,
                           depth=total * (k / n) - total * ((k - 1) / n)))
            return t + duration
        if kind == "release":
            f = self.fields(line, kind, arg, {"handle"}, shorthand="handle")
            h = self.handle(line, kind, f)
            self.held.discard(h)
            add(Action(t, "release", h, line))
            return t
        if kind == "wait":
            if isinstance(arg, dict):
                arg = self.fields(line, kind, arg, {"s"}).get("s")
            return t + self.number(line, kind, arg, "the time (seconds)", 0.0, 86400.0)
        if kind in ("load_preset", "save_preset"):
            if kind == "load_preset":
                self.held.clear()  # the deformer lets go of every pointer
            add(Action(t, "command", self.default_handle, line, command=kind, argument=self.path(line, kind, arg)))
            return t
        if kind == "command":
            from facesculpt.msgs.types import INPUT_COMMANDS

            f = self.fields(line, kind, arg, {"name", "argument"}, shorthand="name")
            name = f.get("name")
            if name not in INPUT_COMMANDS:
                self.fail(line, f"command: {name!r} is not one of {', '.join(INPUT_COMMANDS)}")
            argument = f.get("argument", "")
            if name in ("reset", "undo", "load_preset"):
                self.held.clear()
            add(Action(t, "command", self.default_handle, line, command=name,
                       argument="" if argument is None else str(argument)))
            return t
        # parallel: each branch (a step, or a list of steps) starts now; the longest one ends it
        if not isinstance(arg, list) or not arg:
            self.fail(line, "parallel: needs a list of steps that run at the same time")
        end = t
        for branch, branch_node in zip(arg, node.value[0][1].value):
            if isinstance(branch, list):
                end = max(end, self.sequence(branch, branch_node.value, t))
            else:
                end = max(end, self.step(branch, branch_node, t))
        return end


class ScriptPlayer:
    """Plays a compiled script: :meth:`due` returns the events whose time has come.

    Times are seconds from the start of the play. Pixel drags start where their pointer is:
    the pressed pixel, or for a press at a landmark the landmark's pixel from ``locate(name)``
    at the drag's first event.
    """

    def __init__(self, script: GestureScript):
        self.script = script
        self.next = 0
        self.pointers: dict[int, tuple[float, float] | str] = {}  # handle -> pixel or landmark name
        self.drag_starts: dict[int, tuple[float, float]] = {}

    @property
    def done(self) -> bool:
        return self.next >= len(self.script.actions)

    def finished(self, t: float) -> bool:
        """Every action played and the script's duration (trailing waits included) elapsed."""
        return self.done and t >= self.script.duration

    def due(self, t: float, locate: Callable[[str], tuple[float, float]] | None = None) -> list[dict]:
        """Events (dicts of InputEvent fields) of every action due by ``t`` s, in script order.
        Raises ScriptError (naming the line) when an action cannot be played; the actions after
        it stay due."""
        out: list[dict] = []
        actions = self.script.actions
        while self.next < len(actions) and actions[self.next].t <= t + 1e-9:
            a = actions[self.next]
            self.next += 1
            out.append(self._event(a, locate))
        return out

    def _event(self, a: Action, locate) -> dict:
        if a.kind == "press":
            if a.landmark:
                self.pointers[a.handle] = a.landmark
                return dict(kind="press", landmark=a.landmark, handle=a.handle)
            self.pointers[a.handle] = a.xy
            return dict(kind="press", x=a.xy[0], y=a.xy[1], handle=a.handle)
        if a.kind == "release":
            self.pointers.pop(a.handle, None)
            return dict(kind="release", handle=a.handle)
        if a.kind == "move":
            return dict(kind="move", vector=np.asarray(a.vector, np.float32), handle=a.handle)
        if a.kind == "depth":
            return dict(kind="depth", depth=a.depth, handle=a.handle)
        if a.kind == "command":
            return dict(kind="command", command=a.command, argument=a.argument, handle=a.handle)
        # drag_px
        start = self.drag_starts.get(a.step_id)
        if start is None:
            where = self.pointers.get(a.handle)
            if where is None:
                raise ScriptError(f"{self.script.source} line {a.line}: drag of handle {a.handle} without a press")
            if isinstance(where, str):
                if locate is None:
                    raise ScriptError(f"{self.script.source} line {a.line}: a pixel drag from landmark {where!r} "
                                      "needs the face's pixels (no face/state yet)")
                try:
                    where = tuple(float(c) for c in locate(where))
                except InputError as exc:
                    raise ScriptError(f"{self.script.source} line {a.line}: {exc}") from None
            start = self.drag_starts[a.step_id] = where
        x = start[0] + a.total[0] * a.frac
        y = start[1] + a.total[1] * a.frac
        self.pointers[a.handle] = (x, y)
        return dict(kind="drag", x=x, y=y, handle=a.handle)
