"""The expression basis of model-based coding: the principal components of a person's expression
displacements, and each frame's coefficients in it.

Used by `facesculpt encode` (the basis of the whole video) and the live encoder node (the basis of
the frames it learns from before it sends its key).
"""

from __future__ import annotations

import numpy as np


def expression_basis(displacements: np.ndarray, components: int) -> tuple[np.ndarray, np.ndarray]:
    """mean (3V,) and basis (C, 3V) float64, orthonormal rows, C = min(components, F): the leading
    principal components of ``displacements`` (F, V, 3) mm (each frame's fitted shape minus the
    person's neutral); ValueError without a frame."""
    E = np.asarray(displacements, np.float64).reshape(len(displacements), -1)
    if len(E) == 0:
        raise ValueError("an expression basis needs at least one frame")
    mean = E.mean(0)
    _, _, Vt = np.linalg.svd(E - mean, full_matrices=False)
    return mean, Vt[:int(components)]


def expression_coefficients(displacements: np.ndarray, mean: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """(F, C) float64 the coefficients of ``displacements`` (F, V, 3) or (V, 3) mm in ``basis``
    (C, 3V) about ``mean`` (3V,) (least squares: the basis is orthonormal)."""
    E = np.asarray(displacements, np.float64).reshape(-1, np.asarray(mean).size)
    return (E - mean) @ np.asarray(basis, np.float64).T
