"""What a topic name may be: one or more words of letters, digits, ``_``, ``.`` or ``-`` joined by
``/`` (``camera/image``, ``diagnostics``). Below :mod:`.parameters` (a topic parameter's value is
checked here) and :mod:`.topics` (which topics a node uses)."""

from __future__ import annotations

import re

# Every node publishes its diagnostics here (facesculpt.runtime.node); a renderer may show them.
DIAGNOSTICS_TOPIC = "diagnostics"
_WORD = r"[A-Za-z0-9_][A-Za-z0-9_.\-]*"
_TOPIC = re.compile(rf"{_WORD}(/{_WORD})*\Z")


def topic_problem(name) -> str:
    """Why ``name`` is not a topic name, as the end of a sentence; "" when it is one."""
    if not isinstance(name, str):
        return f"{name!r} is not a string"
    if not _TOPIC.match(name):
        return (f"{name!r} is not a topic name (words of letters, digits, _ . - joined by /, "
                f"as in camera/image)")
    return ""
