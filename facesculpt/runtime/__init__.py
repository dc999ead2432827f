"""The graph middleware: node base, pub/sub, master, launcher, bags, security.

This layer imports :mod:`facesculpt.msgs` and :mod:`facesculpt.paths` only: never a node
(:mod:`facesculpt.nodes`) nor a command (:mod:`facesculpt.app`); tests/test_layers.py checks it.
Writing a node::

    from facesculpt.runtime import Node
"""

from facesculpt.runtime.node import Node

__all__ = ["Node"]
