"""The reenact room (docs/architecture.md "Rooms"): talking heads, one face's expression carried
onto another's, or coded as a few bytes a frame.

``reenact`` (:mod:`.node`) turns a driving face's ``face/state`` and neutral ``face/model``
(remapped, e.g. ``driver/state``, ``driver/model``) into the ``face/deformation`` that the renderer
merges into the source face (paper Eq. 5), so the live graph animates one camera's face with
another's. Its pure part: :mod:`.transfer`.

``encoder`` (:mod:`.encoder_node`) codes a live face as a keyframe, an expression basis and a
27-byte record a frame (model-based coding, :mod:`.live_encoder`, :mod:`.expression_basis`) on
``coding/key``, ``coding/basis`` and ``coding/frame``, which the renderer room's ``decoder``
renders, here or on another machine (facesculpt/launch/coding.yaml).
"""

from .transfer import expression_displacement, model_space_shape

__all__ = ["expression_displacement", "model_space_shape"]
