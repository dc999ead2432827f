"""The gesture-script format (docs/graph/scripts.md): YAML steps compiled into timed actions,
and their player (time -> events). No sockets, no clocks: callers pass text or a path and
times (seconds) in, and get plain dicts of ``InputEvent`` fields out
(facesculpt.msgs.InputEvent(**fields) builds the message).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from .face_targets import InputError


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
    """Compile a gesture script (YAML text, format in docs/graph/scripts.md) into timed actions.

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
        """Compile one step (its YAML ``node`` gives the line) starting at ``t`` s; returns its end (s)."""
        line = _line_of(node)
        if isinstance(step, str):
            kind, arg = step, None
        elif isinstance(step, dict) and len(step) == 1:
            kind, arg = next(iter(step.items()))
        else:
            self.fail(line, f"a step is one of {', '.join(STEP_KINDS)} (e.g. '- press: nose_tip'), got {step!r}")
        if kind not in STEP_KINDS:
            self.fail(line, f"unknown step {kind!r} (known: {', '.join(STEP_KINDS)})")
        if kind in ("load_preset", "save_preset"):
            return self.preset_step(line, kind, arg, t)
        if kind == "parallel":
            return self.parallel_step(line, arg, node, t)
        compile_step = {"press": self.press_step, "drag": self.drag_step, "depth": self.depth_step,
                        "release": self.release_step, "wait": self.wait_step, "command": self.command_step}[kind]
        return compile_step(line, arg, t)

    def press_step(self, line: int, arg, t: float) -> float:
        kind = "press"
        f = self.fields(line, kind, arg, {"landmark", "pixel", "handle"}, shorthand="landmark")
        h = self.handle(line, kind, f)
        self.held.add(h)
        if ("landmark" in f) == ("pixel" in f):
            self.fail(line, "press: give exactly one of landmark (a name) or pixel ([x, y])")
        if "landmark" in f:
            name = f["landmark"]
            if not isinstance(name, (str, int)) or isinstance(name, bool) or not str(name).strip():
                self.fail(line, f"press: landmark must be a name, got {name!r}")
            self.actions.append(Action(t, "press", h, line, landmark=str(name).strip()))
        else:
            self.actions.append(Action(t, "press", h, line, xy=self.vector(line, kind, f["pixel"], 2, "pixel")))
        return t

    def drag_step(self, line: int, arg, t: float) -> float:
        kind = "drag"
        f = self.fields(line, kind, arg, {"mm", "px", "duration_s", "handle"})
        h = self.held_handle(line, kind, f)
        if ("mm" in f) == ("px" in f):
            self.fail(line, "drag: give exactly one of mm ([x, y, z], model space) or px ([dx, dy], image)")
        duration, n = self.ticks(line, kind, f)
        add = self.actions.append
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

    def depth_step(self, line: int, arg, t: float) -> float:
        kind = "depth"
        f = self.fields(line, kind, arg, {"mm", "duration_s", "handle"}, shorthand="mm")
        h = self.held_handle(line, kind, f)
        if "mm" not in f:
            self.fail(line, "depth: needs mm (+ toward the camera)")
        total = self.number(line, kind, f["mm"], "mm")
        duration, n = self.ticks(line, kind, f)
        for k in range(1, n + 1):
            self.actions.append(Action(self.at(t, duration, k, n), "depth", h, line,
                                       depth=total * (k / n) - total * ((k - 1) / n)))
        return t + duration

    def release_step(self, line: int, arg, t: float) -> float:
        f = self.fields(line, "release", arg, {"handle"}, shorthand="handle")
        h = self.handle(line, "release", f)
        self.held.discard(h)
        self.actions.append(Action(t, "release", h, line))
        return t

    def wait_step(self, line: int, arg, t: float) -> float:
        if isinstance(arg, dict):
            arg = self.fields(line, "wait", arg, {"s"}).get("s")
        return t + self.number(line, "wait", arg, "the time (seconds)", 0.0, 86400.0)

    def preset_step(self, line: int, kind: str, arg, t: float) -> float:
        if kind == "load_preset":
            self.held.clear()  # the deformer lets go of every pointer
        self.actions.append(Action(t, "command", self.default_handle, line, command=kind,
                                   argument=self.path(line, kind, arg)))
        return t

    def command_step(self, line: int, arg, t: float) -> float:
        from facesculpt.msgs.types import INPUT_COMMANDS

        kind = "command"
        f = self.fields(line, kind, arg, {"name", "argument"}, shorthand="name")
        name = f.get("name")
        if name not in INPUT_COMMANDS:
            self.fail(line, f"command: {name!r} is not one of {', '.join(INPUT_COMMANDS)}")
        argument = f.get("argument", "")
        if name in ("reset", "undo", "load_preset"):
            self.held.clear()
        self.actions.append(Action(t, "command", self.default_handle, line, command=name,
                                   argument="" if argument is None else str(argument)))
        return t

    def parallel_step(self, line: int, arg, node, t: float) -> float:
        """Each branch (a step, or a list of steps) starts now; the longest one ends the step."""
        if not isinstance(arg, list) or not arg:
            self.fail(line, "parallel: needs a list of steps that run at the same time")
        end = t
        for branch, branch_node in zip(arg, node.value[0][1].value):
            if isinstance(branch, list):
                end = max(end, self.sequence(branch, branch_node.value, t))
            else:
                end = max(end, self.step(branch, branch_node, t))
        return end


def _located(landmark: str, locate: Callable[[str], tuple[float, float]] | None) -> tuple[float, float] | None:
    """The landmark's pixel from ``locate``; None without one or while it cannot say."""
    if locate is None:
        return None
    try:
        return tuple(float(c) for c in locate(landmark))
    except InputError:
        return None


class ScriptPlayer:
    """Plays a compiled script: :meth:`due` returns the events whose time has come.

    Times are seconds from the start of the play. Pixel drags start where their pointer is:
    the pressed pixel, or for a press at a landmark the landmark's pixel from ``locate(name)``
    at the press (sent with it), else at the drag's first event.
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
                # The landmark's pixel as this player sees it goes with the press, and the drags
                # start from it: the deformer then measures them from the same pixel, not from
                # its own (later or earlier) frame's, where a moving head would add its motion.
                xy = _located(a.landmark, locate)
                self.pointers[a.handle] = a.landmark if xy is None else xy
                extra = {} if xy is None else {"x": xy[0], "y": xy[1]}
                return dict(kind="press", landmark=a.landmark, handle=a.handle, **extra)
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
