"""The one command-line entry point, `facesculpt`.

Each subcommand lives beside the code it drives: a module in COMMAND_MODULES
exposes ``register(subparsers)``, which adds its parser(s) and sets
``func(args) -> int`` as the default. Adding a command is one line here.

A command line that names a command imports only the module that owns it: a node process
(``facesculpt run NODE``, which a launcher respawns) does not pay for the other commands' imports
(OpenCV, the pipeline, ...). Without a known command, every module is imported (``--help``).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import warnings

#: module -> the commands its ``register`` adds (tests/test_cli_failures.py checks the two agree)
COMMAND_MODULES = {
    "facesculpt.app.graph_commands": ("master", "run", "launch", "node", "topic", "bag"),
    "facesculpt.app.demo": ("demo",),  # the main job
    "facesculpt.app.model_commands": ("model",),  # model import-eos, model info
    "facesculpt.app.setup_models": ("setup",),
    "facesculpt.app.keys_command": ("keys",),  # keys generate
    "facesculpt.app.process_command": ("process",),
    "facesculpt.app.reenact": ("reenact",),
    "facesculpt.app.coding_commands": ("encode", "decode"),
    "facesculpt.app.bench": ("bench",),
    "facesculpt.app.docs_command": ("docs",),  # serve the documentation site
}


def _command_modules(argv: list[str] | None) -> list[str]:
    """The modules to import for ``argv``: the one owning its command (the first word that is not
    an option), else all of them."""
    command = next((a for a in (argv or []) if not a.startswith("-")), None)
    owner = [m for m, commands in COMMAND_MODULES.items() if command in commands]
    return owner or list(COMMAND_MODULES)


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser of every command, or, given the command line ``argv`` (without the program
    name), of the command it names only."""
    from facesculpt import __version__

    parser = argparse.ArgumentParser(
        prog="facesculpt",
        description="Real-time 3D freeform manipulation of a face in live video.",
    )
    parser.add_argument("--version", action="version", version=f"facesculpt {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _command_modules(argv):
        importlib.import_module(name).register(sub)
    describe_subcommands(parser)
    return parser


def describe_subcommands(parser: argparse.ArgumentParser) -> None:
    """Every subcommand's ``--help`` opens with a description: its own, or else the one-line help
    it is listed with in its parent's ``--help`` (as a sentence)."""
    for action in parser._actions:
        if not isinstance(action, argparse._SubParsersAction):
            continue
        listed = {choice.dest: choice.help for choice in action._choices_actions}
        for name, subparser in action.choices.items():
            line = (listed.get(name) or "").strip()
            if not subparser.description and line:
                subparser.description = line[0].upper() + line[1:] + ("" if line.endswith(".") else ".")
            describe_subcommands(subparser)


def main(argv: list[str] | None = None) -> int:
    from facesculpt.runtime.node import LOG_FORMAT

    parser = build_parser(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format=LOG_FORMAT,
        datefmt="%H:%M:%S",
    )
    # facesculpt's own deprecations reach the command line's user (Python shows them only to __main__)
    warnings.filterwarnings("default", category=DeprecationWarning, module=r"facesculpt\b")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except (FileNotFoundError, ValueError, RuntimeError) as exc:
        # Expected user-facing failures: one clear sentence, no traceback.
        print(f"facesculpt: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
