"""The graph middleware: node base, pub/sub, master, launcher, bags, security.

This layer imports :mod:`facesculpt.msgs` and :mod:`facesculpt.paths` only: never a node
(:mod:`facesculpt.nodes`) nor a command (:mod:`facesculpt.app`); tests/test_layers.py checks it.
Writing a node::

    from facesculpt.runtime import EVENTS, Node, Param
"""

from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import Param
from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE, LATCHED, SENSOR_DATA, QoSProfile

__all__ = ["EVENTS", "EVERY_MESSAGE", "LATCHED", "Node", "Param", "QoSProfile", "SENSOR_DATA"]
