"""The deformer's one error type (raised by the ARAP solver, the edit stack and the node)."""


class DeformerError(ValueError):
    """Bad input to the deformer: indices out of range or not integers, overlapping or
    duplicated anchor sets, an empty ROI, non-finite or wrongly shaped positions, a name
    that is not a landmark of the model, a preset that does not fit the model."""
