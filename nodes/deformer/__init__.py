"""ARAP deformation of the neutral face model from input events (DESIGN.md step 3).

Library: :class:`ArapDeformer` (Sorkine & Alexa 2007), :func:`merge_deformation` (the paper's
Eq. 5), edit layers and presets (:class:`EditStack`), picking and dragging helpers. The node
(``node.py``) turns ``input/events`` into ``face/deformation``.
"""

from .arap import ArapDeformer, DeformerError, arap_energy, cotangent_weights, fit_rotations
from .edits import EditStack
from .merge import merge_deformation

__all__ = [
    "ArapDeformer",
    "DeformerError",
    "EditStack",
    "arap_energy",
    "cotangent_weights",
    "fit_rotations",
    "merge_deformation",
]
