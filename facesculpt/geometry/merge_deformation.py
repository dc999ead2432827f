"""The paper's Eq. 5: merge the fitted mesh of a frame with the user's deformation,
M' = M_fitted + W (M_m - M_bar), the model-space displacement turned into the head pose."""

from __future__ import annotations

import numpy as np


def merge_deformation(
    fitted_vertices: np.ndarray,
    R: np.ndarray,
    scale: float,
    displacement: np.ndarray,
    weights: np.ndarray | float | None = None,
) -> np.ndarray:
    """Deformed fitted mesh in camera space.

    fitted_vertices: (V, 3) camera space (``x_cam = scale * R @ x_model + t``, FaceState).
    R: (3, 3) rotation and scale: float, the pose of that frame (model -> camera).
    displacement: (V, 3) model space, mm (Deformation.displacement, i.e. M_m - M_bar).
    weights: W, per-vertex (V,) or one number in [0, 1] (None: 1), e.g. to fade an edit in.
    Returns (V, 3) in the dtype of ``fitted_vertices`` (float32 stays float32).
    """
    Vf = np.asarray(fitted_vertices)
    D = np.asarray(displacement)
    if Vf.ndim != 2 or Vf.shape[1] != 3 or D.shape != Vf.shape:
        raise ValueError(f"fitted_vertices {Vf.shape} and displacement {D.shape} must both be (V, 3)")
    Rm = np.asarray(R, dtype=np.float64)
    if Rm.shape != (3, 3):
        raise ValueError(f"R must be (3, 3), got {Rm.shape}")
    moved = (float(scale) * D.astype(np.float64)) @ Rm.T
    if weights is not None:
        w = np.asarray(weights, dtype=np.float64)
        moved = moved * (w[:, None] if w.ndim == 1 else w)
    out_dtype = Vf.dtype if np.issubdtype(Vf.dtype, np.floating) else np.float64
    return (Vf.astype(np.float64) + moved).astype(out_dtype)
