"""A launch file's nodes checked against their classes before any process starts.

Every node entry, the ones left out (``enabled: false``) too, is checked for: its type (a
built-in name, ``module:Class`` or ``path/file.py:Class``: the class is loaded, nothing is
started), its parameters (names, types, ranges and choices as its ``PARAMS`` declares them,
overrides included), and its remaps (both sides topic names, and the topic renamed one the node
uses: :func:`facesculpt.runtime.topics.node_topics`). The first problem is a ValueError in one
sentence naming the file, the node and what is wrong, so the whole file is refused at once
instead of a graph that runs broken.

The runtime knows no node: ``node_class`` (a type name -> Node subclass) comes from the
application, which holds the table of built-in nodes.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from facesculpt.runtime.parameters import ParameterError, resolve_params
from facesculpt.runtime.topic_names import topic_problem
from facesculpt.runtime.topics import node_topics


def check_nodes(path: Path, specs: list, node_class: Callable[[str], type]) -> None:
    """Check every :class:`~facesculpt.runtime.launcher.NodeSpec` of launch file ``path`` (as
    written, overrides applied); ValueError in one sentence at the first problem.

    Loading a class imports its module here; what an import does to the environment is undone
    (OpenCV's adds its folder and the current directory to LD_LIBRARY_PATH), so the graph's
    processes start with the environment they had before the check."""
    env = dict(os.environ)
    try:
        _check_each(path, specs, node_class)
    finally:
        if dict(os.environ) != env:
            os.environ.clear()
            os.environ.update(env)


def _check_each(path: Path, specs: list, node_class: Callable[[str], type]) -> None:
    for spec in specs:
        where = f"launch file {path}: node {spec.name}"
        try:
            cls = node_class(spec.node)
        except (ValueError, FileNotFoundError) as exc:
            raise ValueError(f"{where}: {exc}") from None
        except Exception as exc:  # a user's node file that fails to import: its own error, named
            raise ValueError(f"{where}: cannot load node {spec.node!r} ({type(exc).__name__}: {exc})") from None
        try:
            values = resolve_params(spec.name, cls.PARAMS, spec.params)
        except ParameterError as exc:
            raise ValueError(f"launch file {path}: {exc}") from None
        _check_remaps(where, spec, node_topics(cls, values))


def _check_remaps(where: str, spec, used: set[str] | None) -> None:
    """Both sides of each remap are topic names, and what is renamed is a topic the node uses
    (when its class declares them: ``used`` is None otherwise)."""
    for source, target in spec.remap.items():
        for name in (source, target):
            problem = topic_problem(name)
            if problem:
                raise ValueError(f"{where}: remap {source}: {target}: {problem}")
        if used is not None and source not in used:
            raise ValueError(f"{where}: remap {source}: {target}: node type {spec.node} uses no topic {source} "
                             f"(it uses {', '.join(sorted(used))})")


def summary(path: Path, specs: list) -> str:
    """One line saying what launch file ``path`` starts (after :func:`check_nodes` passed)."""
    started = [s.name for s in specs if s.enabled]
    left = [s.name for s in specs if not s.enabled]
    remaps = sum(len(s.remap) for s in specs)
    return (f"launch file {path}: ok: starts {len(started)} node(s) ({', '.join(started)})"
            + (f", leaves out {len(left)} ({', '.join(left)})" if left else "")
            + (f"; {remaps} remap(s)" if remaps else ""))
