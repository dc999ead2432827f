"""Reference pages generated from the code, so they cannot drift from it: every built-in node's
parameters (its ``PARAMS``) and every command's arguments (the ``facesculpt`` argparse tree).

The documentation site's build hook (``docs/hooks/reference.py``, ``mkdocs.yml``) writes
:func:`node_params_markdown` and :func:`cli_markdown` as pages; ``facesculpt run NODE --help``
and ``facesculpt COMMAND --help`` print the same facts.
"""

from __future__ import annotations

import argparse
import os

from facesculpt.runtime.node import load_node_class
from facesculpt.runtime.parameters import EXIT_BAD_PARAMETER, declared


def _cell(text: object) -> str:
    """``text`` fit for one cell of a Markdown table: on one line, pipes and brackets escaped (a
    ``[--name N]`` would read as a link)."""
    return " ".join(str(text).split()).replace("|", "\\|").replace("[", "\\[").replace("]", "\\]")


def _code(value: object) -> str:
    return "`" + repr(value).replace("|", "\\|").replace("`", "'") + "`"


def _allowed(param) -> str:
    if param.range is not None:
        return param.range_text()
    if param.choices is not None:
        return ", ".join(f"`{choice}`" for choice in param.choices)
    return ""


def node_markdown(short_name: str, cls) -> str:
    """One node's section: its name, what it is (its docstring's first paragraph) and a table
    of its parameters (name, type, default, range or choices, description)."""
    doc = (cls.__doc__ or "").strip().split("\n\n")[0]
    lines = [f"## `{short_name}`", "", f"`facesculpt run {short_name}` ({cls.__module__}:{cls.__name__})", ""]
    if doc:
        lines += [" ".join(doc.split()), ""]
    params = declared(cls.PARAMS)
    if not params:
        return "\n".join(lines + ["No parameters.", ""])
    lines += ["| parameter | type | default | range or choices | description |",
              "| --- | --- | --- | --- | --- |"]
    for name, param in params.items():
        lines.append(f"| `{name}` | {param.type_name} | {_code(param.default)} | {_allowed(param)} | "
                     f"{_cell(param.description)} |")
    return "\n".join(lines + [""])


def node_params_markdown(builtin: dict[str, str]) -> str:
    """The node parameter reference: one section per node of ``builtin`` (short name ->
    ``module:Class``, as ``facesculpt.nodes.BUILTIN_NODES``)."""
    intro = [
        "# Node parameters",
        "",
        "Generated from each built-in node's `PARAMS` when the site is built. Set a parameter as "
        "`name=value` after `facesculpt run NODE`, as `NODE.name=value` after `facesculpt launch FILE`, "
        "or under the node's `params:` in a launch file. A value out of its range or not among its "
        f"choices stops the node with one sentence and exit code {EXIT_BAD_PARAMETER} "
        "([Your own node](own-node.md#parameters)). `facesculpt run NODE --help` prints the same table.",
        "",
    ]
    sections = [node_markdown(name, load_node_class(name, builtin)) for name in builtin]
    return "\n".join(intro) + "\n" + "\n".join(sections)


def _subparsers(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.ArgumentParser, str]]:
    """``(name, parser, help)`` of each subcommand of ``parser``, in the order they were added."""
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {choice.dest: choice.help for choice in action._choices_actions}
            found += [(name, sub, helps.get(name) or "") for name, sub in action.choices.items()]
    return found


def _argument_rows(parser: argparse.ArgumentParser) -> list[str]:
    rows = []
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)) or action.help == argparse.SUPPRESS:
            continue
        name = ", ".join(action.option_strings) or action.metavar or action.dest
        default = "" if action.default in (None, argparse.SUPPRESS) or action.option_strings == [] else _code(action.default)
        if isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction)) or action.nargs == 0:
            default = ""
        name = name.replace("|", "\\|")
        rows.append(f"| `{name}` | {default} | {_cell(action.help or '')} |")
    return rows


def _command_markdown(path: str, parser: argparse.ArgumentParser, summary: str, level: int) -> list[str]:
    lines = [f"{'#' * level} `{path}`", ""]
    if summary:
        lines += [summary[0].upper() + summary[1:] + ("" if summary.endswith(".") else "."), ""]
    lines += ["```text", parser.format_usage().strip(), "```", ""]
    rows = _argument_rows(parser)
    if rows:
        lines += ["| argument | default | description |", "| --- | --- | --- |", *rows, ""]
    for name, sub, helptext in _subparsers(parser):
        lines += _command_markdown(f"{path} {name}", sub, helptext, min(level + 1, 4))
    return lines


def cli_markdown(parser: argparse.ArgumentParser) -> str:
    """The command-line reference: every command and subcommand of ``parser`` (the ``facesculpt``
    command's, ``facesculpt.cli.build_parser()``) with its usage and its arguments' defaults and
    help, walked from the argparse tree."""
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"  # argparse wraps the usage lines at this width
    try:
        lines = ["# Command line", "",
                 "Generated from the `facesculpt` command's argparse tree when the site is built; "
                 "`facesculpt COMMAND --help` prints the same. The parameters of "
                 "`facesculpt run NODE` are in [Node parameters](../graph/nodes.md).", ""]
        for name, sub, helptext in _subparsers(parser):
            lines += _command_markdown(f"facesculpt {name}", sub, helptext, 2)
        return "\n".join(lines)
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old
