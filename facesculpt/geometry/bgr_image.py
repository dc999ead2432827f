"""Any image a user may hand a detector, as the (H, W, 3) uint8 BGR image the networks' crops
are taken from (the landmarks and hands rooms share it)."""

from __future__ import annotations

import cv2
import numpy as np


def as_bgr_uint8(image) -> np.ndarray | None:
    """Coerce an image to (H, W, 3) uint8 BGR; None when it holds no pixels or is not an image.

    Accepts grey (H, W) or (H, W, 1), BGRA, float images (in [0, 1] when their maximum is at
    most 1, else [0, 255]), and other integer types (uint16 is scaled to 8 bits).
    """
    if not isinstance(image, np.ndarray):
        try:
            image = np.asarray(image)
        except Exception:  # noqa: BLE001 - anything not array-like is "not an image"
            return None
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim not in (2, 3) or image.size == 0 or (image.ndim == 3 and image.shape[2] not in (3, 4)):
        return None
    if image.dtype != np.uint8:
        if image.dtype == np.bool_:
            image = image.astype(np.uint8) * 255
        elif np.issubdtype(image.dtype, np.floating):
            img = np.nan_to_num(image.astype(np.float32), nan=0.0, posinf=255.0, neginf=0.0)
            if img.max(initial=0.0) <= 1.0:
                img = img * 255.0
            image = np.clip(img + 0.5, 0, 255).astype(np.uint8)
        elif image.dtype == np.uint16:
            image = (image >> 8).astype(np.uint8)
        elif np.issubdtype(image.dtype, np.integer):
            image = np.clip(image, 0, 255).astype(np.uint8)
        else:
            return None
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.shape[2] == 4:
        return np.ascontiguousarray(image[:, :, :3])
    return np.ascontiguousarray(image)
