"""facesculpt: real-time 3D freeform manipulation of a face in live video.

The runtime every node imports lives here (pub/sub, node base, master, launch,
bags, CLI, paths); message types are in :mod:`facesculpt.msgs`, the built-in
nodes and their algorithms in :mod:`facesculpt.nodes`.
"""

__version__ = "0.1.0"
