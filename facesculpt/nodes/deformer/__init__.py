"""ARAP deformation of the neutral face model from input events (docs/architecture.md, stage 3).

Library: :class:`ArapDeformer` (Sorkine & Alexa 2007), edit layers and presets (:class:`EditStack`), picking and dragging helpers. The node
(``node.py``) turns ``input/events`` into ``face/deformation``.
"""

from .arap import ArapDeformer
from .edits import EditStack
from .energy import arap_energy, cotangent_weights
from .errors import DeformerError
from .rotations import fit_rotations

__all__ = [
    "ArapDeformer",
    "DeformerError",
    "EditStack",
    "arap_energy",
    "cotangent_weights",
    "fit_rotations",
]
