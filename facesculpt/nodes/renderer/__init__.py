"""Rendering (docs/architecture.md "Stages", 4): texture update, inpainting, compositing; window / video / topic.

Library use, without the graph::

    from facesculpt.nodes.renderer import Compositor
    comp = Compositor(width, height)                 # headless EGL context of its own
    out = comp.render(frame_bgr, fitted_vertices, projected_px, triangles, deformed_vertices)

:class:`Compositor` (compositor.py) draws the deformed face; :mod:`.inpaint` has the
fills (push-pull, Telea); :class:`FramePairer` (pairing.py) the sync/latest pairing;
:class:`RendererNode` (node.py) is the graph's thin shell around them.
"""

from facesculpt.nodes.renderer.compositor import Compositor
from facesculpt.nodes.renderer.inpaint import INPAINT_METHODS, fill_pushpull, fill_telea, uncovered_mask
from facesculpt.nodes.renderer.pairing import PAIRING_MODES, FramePairer, Pair

__all__ = [
    "Compositor",
    "FramePairer",
    "INPAINT_METHODS",
    "PAIRING_MODES",
    "Pair",
    "fill_pushpull",
    "fill_telea",
    "uncovered_mask",
]
