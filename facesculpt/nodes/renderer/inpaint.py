"""Filling the background that a shrinking face uncovers (docs/architecture.md "Stages", 4).

The region to fill is the original face region minus the deformed face region,
slightly dilated (:func:`uncovered_mask`). It is filled from the surrounding
*background* — pixels outside the original face — inwards, never from the old
face texture, so nothing of the face is smeared into the place it left.

Two fills, both working on a crop (:func:`fill_by_parts`: each connected part of the region
on its own bounding box plus a margin):

* :func:`fill_pushpull` (default, fast): a pull-push pyramid (Gortler et al.
  1996, the "Lumigraph" hole filler): known pixels are averaged down a
  Gaussian pyramid with their weights, then the coarse averages are pulled back
  up into every pixel the fine levels lack. A smooth membrane-like fill in
  O(pixels), a few tenths of a millisecond for a face-sized crop.
* :func:`fill_telea`: OpenCV's Telea fast-marching inpainting on the same crop,
  with every non-source pixel (the whole old face inside the crop) marked
  unknown so that it, too, draws from the background only; "ns": the same with
  OpenCV's Navier-Stokes inpainting.
* "patch" (:mod:`.patch_fill`): the push-pull fill, then tiles of background copied
  in from nearby shifts that match their surroundings, with a pull-push seam
  correction: texture and edges continue into the region.

Images are (h, w, 3) uint8 BGR; masks are (h, w) bool or uint8 (non-zero = set).
"""

from __future__ import annotations

import cv2
import numpy as np

from .pushpull import pushpull_into

INPAINT_METHODS = ("pushpull", "telea", "ns", "patch")
#: The compositor's fills: these, and "drag" (:mod:`.drag_fill`: the background beside the face
#: carried in by its motion, push-pull where that does not reach), which needs the source map.
FILL_METHODS = INPAINT_METHODS + ("drag",)
_SLIVER_KERNEL = np.ones((2, 2), np.uint8)


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Dilate a (h, w) uint8 0/1 mask by a disk of ``radius`` pixels (0: unchanged)."""
    if radius <= 0:
        return mask
    return cv2.dilate(mask, _disk(int(radius)))


def uncovered_mask(original: np.ndarray, deformed: np.ndarray, dilate_px: int = 2) -> np.ndarray:
    """Pixels to inpaint: ``original`` face region minus ``deformed`` face region, dilated.

    original, deformed: (h, w) uint8 0/1 (or bool) coverage of the undeformed and the
    deformed mesh. Parts of the difference thinner than 2 pixels are dropped (outlines that
    differ by rasterisation only). dilate_px: how far the difference grows (pixels, disk); it grows past
    the old face outline by at most this much, which catches the outline's mixed pixels.
    Returns (h, w) uint8 0/1.
    """
    diff = ((original != 0) & (deformed == 0)).astype(np.uint8)
    # Drop slivers one pixel wide: where the two outlines nearly coincide they differ by
    # rasterisation alone, and filling those would print background specks under the
    # feathered edge of the face.
    # Opening by a 2x2 square: the union of the 2x2 squares inside the difference. (The
    # dilation takes the reflected anchor; OpenCV's MORPH_OPEN would shift it by a pixel.)
    core = cv2.erode(diff, _SLIVER_KERNEL, anchor=(0, 0), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    diff = cv2.dilate(core, _SLIVER_KERNEL, anchor=(1, 1), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return dilate(diff, dilate_px)


def fill_pushpull(image: np.ndarray, fill: np.ndarray, source: np.ndarray) -> np.ndarray:
    """Fill the ``fill`` pixels of ``image`` from the ``source`` pixels by pull-push.

    image: (h, w, 3) uint8. fill, source: (h, w) masks; ``source`` pixels are the known
    samples (pixels in neither mask are ignored: neither read nor written).
    Returns a new (h, w, 3) uint8 image equal to ``image`` except at ``fill`` pixels.
    Raises ValueError when there is no source pixel at all.
    """
    fill = fill.astype(bool, copy=False)
    known = source.astype(bool, copy=False) > fill  # source and not fill, as fill_by_parts computes it
    if not known.any():
        raise ValueError("push-pull fill: no source pixel to fill from")
    out = image.copy()
    pushpull_into(out, np.ascontiguousarray(image), fill, known)
    return out


def fill_by_parts(image: np.ndarray, fill: np.ndarray, source: np.ndarray, method: str = "pushpull",
                  margin: int = 8, radius: float = 3.0, in_place: bool = False) -> np.ndarray:
    """Fill each connected part of ``fill`` separately, on its bounding box plus ``margin``
    (parts whose boxes overlap together, on one box: :func:`part_boxes`).

    The uncovered region is usually a few thin bands far apart (one per cheek): their own
    boxes hold a fraction of the pixels of one box around all of them; the specks beside them
    share a box, each fill call costing more than the pixels it fills. Same arguments and
    return as :func:`fill_pushpull` (method "pushpull" or "telea"); a part whose box holds no
    source pixel is filled from the whole image instead. ``in_place``: write into ``image``
    and return it (the parts never read each other's fill pixels: those are no source).
    """
    if method not in INPAINT_METHODS:
        raise ValueError(f"unknown inpaint method {method!r} (known: {', '.join(INPAINT_METHODS)})")
    fill_u8 = fill.astype(np.uint8, copy=False)
    source = source.astype(bool, copy=False)
    if method == "patch":
        from .patch_fill import MARGIN_PX, fill_patch

        margin = max(margin, MARGIN_PX)
    contours, _ = cv2.findContours(fill_u8, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = image if in_place else image.copy()
    h, w = fill.shape
    for x0, y0, x1, y1 in part_boxes([cv2.boundingRect(c) for c in contours], margin, w, h):
        crop = (slice(y0, y1), slice(x0, x1))
        part_fill = fill_u8[crop] != 0
        known = source[crop] > part_fill  # source and not fill, in one operation
        if not known.any():
            crop, part_fill = (slice(0, h), slice(0, w)), fill_u8 != 0
            known = source > part_fill
            if not known.any():
                raise ValueError(f"{method} fill: no source pixel to fill from")
        if method == "pushpull":
            # Reads only known pixels, which no part writes: ``image`` may be ``out``.
            pushpull_into(out[crop], image[crop], part_fill, known)
        elif method == "patch":
            smooth = np.ascontiguousarray(image[crop])
            pushpull_into(smooth, smooth.copy(), part_fill, known)
            done = fill_patch(np.ascontiguousarray(image[crop]), part_fill, known, smooth)
            np.copyto(out[crop], done, where=part_fill[..., None])
        else:
            done = fill_telea(np.ascontiguousarray(image[crop]), part_fill, known, radius,
                              cv2.INPAINT_NS if method == "ns" else cv2.INPAINT_TELEA)
            np.copyto(out[crop], done, where=part_fill[..., None])
    return out


def part_boxes(rects: list, margin: int, width: int, height: int) -> list[tuple[int, int, int, int]]:
    """The boxes (x0, y0, x1, y1) px, cut to ``width`` x ``height``, of parts whose bounding
    ``rects`` (x, y, w, h) are grown by ``margin``: boxes that overlap merged into their common
    box until none overlaps another, so each part lies whole in one box and no box holds part of
    another's."""
    boxes = [[max(0, x - margin), max(0, y - margin), min(width, x + bw + margin), min(height, y + bh + margin)]
             for x, y, bw, bh in rects]
    merged = True
    while merged:
        merged = False
        for i in range(len(boxes)):
            for j in range(len(boxes) - 1, i, -1):
                a, b = boxes[i], boxes[j]
                if a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]:
                    boxes[i] = [min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])]
                    del boxes[j]
                    merged = True
    return [tuple(b) for b in boxes]


def fill_telea(image: np.ndarray, fill: np.ndarray, source: np.ndarray, radius: float = 3.0,
               flags: int = cv2.INPAINT_TELEA) -> np.ndarray:
    """Fill the ``fill`` pixels of ``image`` with OpenCV's Telea inpainting (``flags``
    cv2.INPAINT_NS: Navier-Stokes), reading only ``source``.

    Every pixel outside ``source`` is handed to :func:`cv2.inpaint` as unknown (so the old
    face is not a source), but only ``fill`` pixels are written back. Same shapes and
    return as :func:`fill_pushpull`. radius: Telea's neighbourhood, pixels.
    """
    fill = fill != 0
    if not ((source != 0) & ~fill).any():
        raise ValueError("Telea fill: no source pixel to fill from")
    unknown = ((source == 0) | fill).astype(np.uint8)
    painted = cv2.inpaint(image, unknown, float(radius), flags)
    out = image.copy()
    out[fill] = painted[fill]
    return out
