"""Topic names: what one may be, and which topics a node uses.

A topic name is one or more words of letters, digits, ``_``, ``.`` or ``-`` joined by ``/``
(``camera/image``, ``driver/image``, ``diagnostics``): no spaces, no leading, trailing or double
``/``. A node declares the topics it advertises or subscribes in its ``TOPICS`` (before
remapping); a parameter declared with ``Param(..., topic=True)`` names one more (the camera's
``wait_for``, the landmarks' ``image_topic``). A launch file may remap only these
(:mod:`facesculpt.runtime.launch_check`), and a node that declares ``TOPICS`` may advertise or
subscribe no other (:func:`check_declared`). A node that declares none (a user's own) is not
held to it.
"""

from __future__ import annotations

from facesculpt.runtime.parameters import declared
from facesculpt.runtime.topic_names import DIAGNOSTICS_TOPIC


def node_topics(cls, values: dict) -> set[str] | None:
    """The topics a node of class ``cls`` may advertise or subscribe (before remapping) when it
    runs with the parameter values ``values`` (name -> value): its ``TOPICS``, the topics its
    topic parameters name, and :data:`DIAGNOSTICS_TOPIC`. None when ``cls`` declares no ``TOPICS``."""
    if not getattr(cls, "TOPICS", ()):
        return None
    named = {values.get(name, p.default) for name, p in declared(cls.PARAMS).items() if p.topic}
    return set(cls.TOPICS) | {DIAGNOSTICS_TOPIC} | {t for t in named if t}


def check_declared(node, topic: str) -> None:
    """ValueError naming the node and the topic when ``node`` declares ``TOPICS`` and ``topic``
    (before remapping) is not among the topics it may use (:func:`node_topics`): a node's
    declaration is what a launch file's remaps are checked against, so it must be whole."""
    allowed = node_topics(type(node), node.params.as_dict())
    if allowed is not None and topic not in allowed:
        raise ValueError(f"node {node.name}: topic {topic} is not declared: add it to "
                         f"{type(node).__name__}.TOPICS ({', '.join(sorted(allowed))})")
