"""Options declared once: a stage's options are one dataclass beside its algorithm, each field
made by :func:`option` with its default, unit, valid range (or choices) and help text.

Everything else derives from those fields: the node parameters
(:func:`facesculpt.runtime.parameters.option_params`), the command line's flags
(:func:`facesculpt.app.option_arguments.add_option_argument`) and the in-process
:class:`facesculpt.app.pipeline.Pipeline` (which takes the dataclasses themselves). Below every
layer, like :mod:`facesculpt.paths`: it imports nothing of ours.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import field


def option(default, help_text: str, unit: str = "", range=None, choices=None, none: str = ""):  # noqa: A002
    """A dataclass field with its metadata: ``help`` (what it does), ``unit`` (e.g. "px", "mm²"),
    ``range`` ((lo, hi) inclusive, None on a side: unbounded) or ``choices`` (the values it may
    take), and ``none`` (what None means, when None is allowed besides the range)."""
    return field(default=default, metadata={"help": help_text, "unit": unit, "range": range, "choices": choices,
                                            "none": none})


def described_fields(options) -> list[dataclasses.Field]:
    """The fields of an options dataclass (class or instance) made by :func:`option`."""
    return [f for f in dataclasses.fields(options) if "help" in f.metadata]


def option_help(f: dataclasses.Field, none_word: str = "None") -> str:
    """A field's help text with its unit and what None (called ``none_word``) means: ``"soft edge, px"``."""
    m = f.metadata
    text = m["help"]
    if m.get("unit") and m["unit"] not in text:
        text += f", {m['unit']}"
    if m.get("none"):
        text += f" ({none_word}: {m['none']})"
    return text


def option_problem(f: dataclasses.Field, value) -> str:
    """Why ``value`` is not allowed for field ``f``, as the end of a sentence; "" when it is."""
    m = f.metadata
    if value is None:
        return "" if m.get("none") or f.default is None else "must not be None"
    if m.get("choices") is not None and value not in m["choices"]:
        return f"must be one of {', '.join(repr(c) for c in m['choices'])}, got {value!r}"
    if m.get("range") is not None:
        if isinstance(value, bool) or not isinstance(value, numbers.Real) or math.isnan(value):
            return f"must be a number, got {value!r}"
        lo, hi = m["range"]
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            return f"must be in [{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}], got {value!r}"
    return ""


def check_options(options, error: type[Exception] = ValueError) -> None:
    """Raise ``error`` with one sentence naming the first field of ``options`` (an instance) whose
    value is out of its range or not one of its choices."""
    for f in described_fields(options):
        problem = option_problem(f, getattr(options, f.name))
        if problem:
            raise error(f"{f.name} {problem}")
