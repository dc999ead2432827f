"""Command-line flags made from options fields (:func:`facesculpt.options.option`): the flag's
default, type, choices, range check and help all come from the one declaration, so that
``--help``, the node parameters and the Python API cannot disagree."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from facesculpt.options import option_help, option_problem


def _field(options, name: str) -> dataclasses.Field:
    for f in dataclasses.fields(options):
        if f.name == name:
            return f
    raise KeyError(f"{type(options).__name__} has no option {name!r}")


class _Deprecated(argparse.Action):
    """An old flag: stores into the new one's dest and warns once."""

    def __init__(self, *args, new_flag: str = "", **kwargs):
        self.new_flag = new_flag
        super().__init__(*args, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"facesculpt: warning: {option_string} is now {self.new_flag} (the old name works for one release)",
              file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_option_argument(parser, options, name: str, flag: str, *, metavar: str | None = None,
                        old_flags: tuple[str, ...] = (), extra_help: str = "") -> None:
    """Add ``flag`` to ``parser`` for the field ``name`` of ``options`` (an options dataclass
    instance, whose value is the default): its type, choices, range and help from the field's
    declaration. A choice that may be None is ``off`` on the command line (the value stays "off";
    the caller maps it). ``old_flags``: earlier names of the flag, still accepted with a warning."""
    f = _field(options, name)
    default, choices = getattr(options, name), f.metadata.get("choices")
    if default is None and choices is not None:
        default, choices = "off", ("off", *choices)
    kind = type(default) if default is not None else str

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a {kind.__name__}, got {text!r}") from None
        problem = "" if value == "off" and choices else option_problem(f, value)
        if problem:
            raise argparse.ArgumentTypeError(problem)
        return value

    shown = f"default {default:g}" if isinstance(default, float) else f"default {default}"
    text = f"{option_help(f, 'off' if choices and 'off' in choices else 'None')} ({shown})" + (f"; {extra_help}" if extra_help else "")
    dest = flag.lstrip("-").replace("-", "_")
    parser.add_argument(flag, dest=dest, type=parse, default=default, choices=choices, metavar=metavar,
                        help=text.replace("%", "%%"))
    for old in old_flags:
        parser.add_argument(old, dest=dest, type=parse, choices=choices, action=_Deprecated, new_flag=flag,
                            help=argparse.SUPPRESS)
