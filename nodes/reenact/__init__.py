"""The reenact room (docs/architecture.md "Rooms"): one face's expression carried onto another's.

``reenact`` (:mod:`.node`) turns a driving face's ``face/state`` and neutral ``face/model``
(remapped, e.g. ``driver/state``, ``driver/model``) into the ``face/deformation`` that the renderer
merges into the source face (paper Eq. 5), so the live graph animates one camera's face with
another's. Its pure part: :mod:`.transfer`.
"""

from .transfer import expression_displacement, model_space_shape

__all__ = ["expression_displacement", "model_space_shape"]
