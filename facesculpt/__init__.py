"""facesculpt: real-time 3D freeform manipulation of a face in live video.

Layers (docs/architecture.md): :mod:`facesculpt.runtime` is the graph middleware (node base,
pub/sub, master, launcher, bags, security) and imports no node and no command;
:mod:`facesculpt.geometry` holds the pure functions that several nodes share;
:mod:`facesculpt.msgs` the message types; :mod:`facesculpt.nodes` the built-in nodes and
their algorithms; :mod:`facesculpt.app` the commands (demo, process, bench, setup, ...)
that wire them together; :mod:`facesculpt.cli` the one entry point.
"""

__version__ = "0.1.0"
