"""The pull-push fill at its core: a known region's colours pushed down a pyramid and pulled back
up into the pixels to fill. Shared by the inpainting (:mod:`.inpaint`) and the patch fill's seam
correction (:mod:`.patch_fill`)."""

from __future__ import annotations

import cv2
import numpy as np


def pushpull_into(out: np.ndarray, image: np.ndarray, fill: np.ndarray, known: np.ndarray) -> None:
    """The pull-push fill (:func:`.inpaint.fill_pushpull`), written into the ``fill`` pixels of ``out``.

    out, image (h, w, 3) uint8, views into larger images allowed, the same array allowed (only
    ``known`` pixels are read, only ``fill`` pixels written); fill, known (h, w) bool, disjoint,
    ``known`` not empty. Written for small crops, where each numpy or OpenCV call
    costs microseconds: no boolean indexing, few temporaries."""
    h, w = fill.shape
    known_u8 = known.view(np.uint8)
    # Premultiplied colour and weight pyramids (contiguous arrays: numpy is fast on those).
    weight = known_u8.astype(np.float32)
    colour = cv2.copyTo(image, known_u8, np.zeros((h, w, 3), np.uint8)).astype(np.float32)
    colours, weights = [colour], [weight]
    # Push: average down until every coarse pixel has some known sample (or 1x1).
    while max(weight.shape) > 1:
        colour = cv2.pyrDown(colour)
        weight = cv2.pyrDown(weight)
        colour = colour.reshape(weight.shape[0], weight.shape[1], 3)  # a 1-px-wide level loses its axis
        weight = weight.reshape(colour.shape[:2])
        colours.append(colour)
        weights.append(weight)
        if cv2.minMaxLoc(weight)[0] > 1e-6:
            break
    # Pull: from the coarsest level, lay each finer level over the upsampled coarse fill with the
    # confidence conf = min(1, 4 w) as its alpha. The level's colour is c / w (c premultiplied),
    # so its share is c * conf / w = c * min(4, 1 / w) = c / max(w, 1/4). The confidence saturates
    # where a level has enough known samples, so coarse levels only fill the gaps of finer ones.
    # Level 0 needs no blend: its known pixels stay, its fill pixels take the pulled value.
    filled = colours[-1] / np.maximum(weights[-1], 1e-12)[..., None]
    for k in range(len(colours) - 2, 0, -1):
        lh, lw = weights[k].shape
        up = cv2.pyrUp(filled, dstsize=(lw, lh)).reshape(lh, lw, 3)
        scale = np.maximum(weights[k], 0.25)
        np.divide(1.0, scale, out=scale)  # min(4, 1 / w)
        transparency = 1.0 - weights[k] * scale  # 1 - conf
        filled = colours[k]
        filled *= scale[..., None]
        up *= transparency[..., None]
        filled += up
    up = cv2.pyrUp(filled, dstsize=(w, h)).reshape(h, w, 3)
    # Averages of uint8 values are in range; convertScaleAbs rounds and saturates to uint8.
    cv2.copyTo(cv2.convertScaleAbs(up), fill.view(np.uint8), out)
