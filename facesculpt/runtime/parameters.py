"""Node parameters: declared with a description and a valid range or choices, checked at start
(as rclpy's ``declare_parameter`` with a ``ParameterDescriptor``).

A node lists its parameters in ``PARAMS``, each a :class:`Param` or a plain default::

    PARAMS = {
        "iterations": Param(5, "iterations per frame", range=(1, 50)),
        "outline": Param("ray", "contour correspondences", choices=("ray", "nearest", "off")),
        "gain": 1.5,   # a plain default: its type is the parameter's type, no description or range
    }

The type of the default is the parameter's type: values given as ``name=value`` strings or
from YAML are converted to it (:func:`coerce_param`). :func:`resolve_params` converts and
checks every value given to a node; a wrong one raises :class:`ParameterError` with one
sentence, and a node run from the command line then exits with :data:`EXIT_BAD_PARAMETER`,
which the launcher does not respawn (the same values would fail again).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

from facesculpt.runtime.topic_names import topic_problem

# Exit status of a node stopped by a parameter it cannot run with.
EXIT_BAD_PARAMETER = 2
# Exit status of a node that ends because the user asked the whole graph to stop (the window's
# Q, Escape or close button): the launcher stops every node and exits 0, and never respawns it.
EXIT_STOP_GRAPH = 3
# Exit status of a node the user closed on its own (the renderer's window with close=node): it
# ended on purpose, so the launcher neither respawns it nor counts it failed; the rest runs on.
EXIT_NODE_CLOSED = 4


class ParameterError(ValueError):
    """A parameter a node cannot run with (unknown, wrong type, out of range, not a choice)."""


class ConfigurationError(ParameterError):
    """What a parameter names cannot be used (a missing model file, no display for a window, no
    camera at that index): raised by a node's setup; the node stops with
    :data:`EXIT_BAD_PARAMETER` and is not respawned, since running it again cannot help."""


@dataclass(frozen=True)
class Param:
    """One declared parameter: its default (whose type is the parameter's type), what it does
    (with its unit), and the values it may take: ``range=(lo, hi)`` inclusive for numbers
    (``None`` on a side: unbounded), or ``choices`` for a fixed set of values. ``topic=True``: the
    value names a topic the node uses (``""``: none), which a launch file may remap
    (:mod:`facesculpt.runtime.topics`). ``check``: a function of a value saying why it is not
    allowed, as the end of a sentence ("" when it is), for values no range or choices describe
    (a comma list of names)."""

    default: Any
    description: str = ""
    range: tuple | None = None
    choices: tuple | None = None
    topic: bool = False
    check: Callable[[Any], str] | None = None

    def __post_init__(self):
        if self.range is not None and self.choices is not None:
            raise ValueError("a parameter takes a range or choices, not both")
        if self.range is not None:
            if not isinstance(self.default, (int, float)) or isinstance(self.default, bool):
                raise ValueError(f"a range needs a numeric default, not {self.default!r}")
            lo, hi = self.range
            if lo is not None and hi is not None and lo > hi:
                raise ValueError(f"empty range [{lo}, {hi}]")
        if self.choices is not None:
            object.__setattr__(self, "choices", tuple(self.choices))
            if not self.choices:
                raise ValueError("choices must not be empty")
        problem = self.problem(self.default)
        if problem:
            raise ValueError(f"default {self.default!r} {problem}")

    @property
    def type_name(self) -> str:
        return "any" if self.default is None else type(self.default).__name__

    def problem(self, value: Any) -> str:
        """Why ``value`` (of the parameter's type) is not allowed, as the end of a sentence; "" if it is."""
        if self.range is not None and value is not None:
            lo, hi = self.range
            if (lo is not None and value < lo) or (hi is not None and value > hi) or math.isnan(value):
                return f"is out of range {self.range_text()}"
        if self.choices is not None and value not in self.choices:
            return f"is not one of {', '.join(map(str, self.choices))}"
        if self.topic and value and topic_problem(value):
            return "is not a topic name (words of letters, digits, _ . - joined by /, as in camera/image)"
        if self.check is not None:
            return self.check(value)
        return ""

    def range_text(self) -> str:
        lo, hi = self.range
        return f"{'(-inf' if lo is None else f'[{lo}'}, {'inf)' if hi is None else f'{hi}]'}"

    def help_text(self) -> str:
        """``int, default 5, range [1, 50]: iterations per frame`` (for ``--help``)."""
        text = f"{self.type_name}, default {self.default!r}"
        if self.range is not None:
            text += f", range {self.range_text()}"
        if self.choices is not None:
            text += f", one of {', '.join(map(str, self.choices))}"
        if self.topic:
            text += ", a topic"
        return text + (f": {self.description}" if self.description else "")


@dataclass(frozen=True)
class Renamed:
    """A parameter's old name in a node's ``PARAMS`` (``"min_cutoff": Renamed("smooth_min_cutoff")``):
    a value given under it goes to the new name, with a warning; it works for one release."""

    new_name: str


def declared(params: dict[str, Any]) -> dict[str, Param]:
    """A node's ``PARAMS`` with plain defaults read as undescribed, unbounded :class:`Param`
    (old names, :class:`Renamed`, left out)."""
    return {name: value if isinstance(value, Param) else Param(value) for name, value in params.items()
            if not isinstance(value, Renamed)}


def renamed(node_name: str, params: dict[str, Any], given: dict[str, Any]) -> dict[str, Any]:
    """``given`` with each old parameter name (:class:`Renamed` in ``params``) replaced by its new
    one, warning once per name."""
    out = {}
    for key, value in given.items():
        old = params.get(key)
        if isinstance(old, Renamed):
            if (node_name, key) not in _WARNED:
                _WARNED.add((node_name, key))
                logging.getLogger("facesculpt").warning(
                    "node %s: param %s is now called %s (the old name works for one release)",
                    node_name, key, old.new_name)
            key = old.new_name
        out[key] = value
    return out


_WARNED: set = set()


def option_params(options, fields, aliases: dict[str, str] | None = None) -> dict[str, Param]:
    """Node parameters declared by an options dataclass (an instance, whose values are the
    defaults): one :class:`Param` per name in ``fields``, in that order, with the description,
    range and choices of the field's metadata (``help``, ``unit``, ``range``, ``choices``). A
    node's own name for a field maps to the field's name through ``aliases``."""
    aliases = aliases or {}
    meta = {f.name: f.metadata for f in dataclasses.fields(options)}
    out = {}
    for name in fields:
        field_name = aliases.get(name, name)
        m = meta[field_name]
        text, unit = m.get("help", ""), m.get("unit", "")
        text = f"{text} ({unit})" if unit and unit not in text else text
        default, choices = getattr(options, field_name), m.get("choices")
        if default is None and choices is not None and m.get("none"):
            # a choice that may be None is "off" on a node (a launch file's value is a string)
            default, choices, text = "off", ("off", *choices), f"{text}; off: {m['none']}"
        out[name] = Param(default, text, range=m.get("range"), choices=choices)
    return out


def default_values(params: dict[str, Any]) -> dict[str, Any]:
    """``{name: default}`` of a node's ``PARAMS``."""
    return {name: p.default for name, p in declared(params).items()}


def coerce_param(name: str, value: Any, default: Any) -> Any:
    """Convert ``value`` (from YAML or a ``name=value`` string) to the type of ``default``."""
    if isinstance(value, str) and not isinstance(default, str):
        import yaml  # here: a node's start-up (its parameters come as JSON) does without it

        try:
            value = yaml.safe_load(value) if value != "" else None
        except yaml.YAMLError:
            raise ValueError(f"param {name}: cannot parse {value!r}") from None
    if default is None or value is None:
        return value
    typ = type(default)
    if typ is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, (int, float)) and value in (0, 1):
            return bool(value)
        raise ValueError(f"param {name}: expected true/false, got {value!r}")
    if typ is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if typ is int and isinstance(value, (int, float)) and not isinstance(value, bool) and float(value).is_integer():
        return int(value)
    if typ is str:
        if isinstance(value, bool):  # YAML 1.1 reads an unquoted on/off (yes/no) as a boolean
            return "on" if value else "off"
        return str(value)
    if isinstance(value, typ):
        return value
    raise ValueError(f"param {name}: expected {typ.__name__}, got {value!r}")


def resolve_params(node_name: str, params: dict[str, Any], given: dict[str, Any]) -> dict[str, Any]:
    """The values a node runs with: the defaults of ``params`` (its ``PARAMS``) overridden by
    ``given``, each converted to its type and checked against its range or choices. Raises
    :class:`ParameterError` naming the node, the parameter, the value and what is allowed."""
    decl = declared(params)
    given = renamed(node_name, params, given)
    unknown = sorted(set(given) - set(decl))
    if unknown:
        known = ", ".join(sorted(decl)) or "none"
        raise ParameterError(f"node {node_name}: unknown param(s) {', '.join(unknown)} (known: {known})")
    values = {name: p.default for name, p in decl.items()}
    for key, value in given.items():
        full = f"{node_name}.{key}"
        try:
            values[key] = coerce_param(full, value, decl[key].default)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        problem = decl[key].problem(values[key])
        if problem:
            raise ParameterError(f"{full}={values[key]!r} {problem}")
    return values


def parse_assignments(items: list[str]) -> dict[str, str]:
    """``["a=1", "b=x"]`` -> ``{"a": "1", "b": "x"}``, with a clear error for a malformed item."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"expected name=value, got {item!r}")
        out[key.strip()] = value
    return out


class Params(SimpleNamespace):
    """Attribute access to a node's parameters (``self.params.fps``)."""

    def as_dict(self) -> dict:
        return dict(vars(self))
