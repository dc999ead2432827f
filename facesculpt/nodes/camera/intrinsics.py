"""Pinhole intrinsics, and the camera's one option about them (:class:`IntrinsicsOptions`: the
field of view assumed when a camera gives no K), declared once for the camera node, the command
line's ``--fov`` and the in-process pipeline."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from facesculpt.options import check_options, option


@dataclass(frozen=True)
class IntrinsicsOptions:
    """What is assumed of a camera that gives no intrinsics."""

    fov_deg: float = option(60.0, "horizontal field of view assumed for the camera, unless it gives K", "degrees",
                            range=(1.0, 179.0))


#: The default field of view, degrees (:class:`IntrinsicsOptions`).
FOV_DEG = IntrinsicsOptions.fov_deg


def intrinsics_from_fov(width: int, height: int, fov_deg: float = FOV_DEG) -> np.ndarray:
    """K (3, 3) float64 for a pinhole camera with horizontal field of view ``fov_deg``,
    square pixels and the principal point at the image centre (pixels)."""
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    check_options(IntrinsicsOptions(fov_deg=fov_deg))
    f = 0.5 * width / math.tan(math.radians(fov_deg) / 2.0)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])
