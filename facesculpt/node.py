"""Deprecated location of the node base: use ``from facesculpt.runtime import Node``."""

import warnings

from facesculpt.runtime.node import Node

warnings.warn("facesculpt.node is deprecated: import Node from facesculpt.runtime",
              DeprecationWarning, stacklevel=2)

__all__ = ["Node"]
