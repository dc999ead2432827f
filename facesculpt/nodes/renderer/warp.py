"""Sampling the input frame through the source map, and the soft edges of what changed
(docs/architecture.md "Stages", 4).

The offset map of :mod:`.source_map` gives, per pixel p of the work box, where in the input
frame its colour comes from (``p + d(p)``). This module turns it into pixels:

* :func:`changed_pixels`: the pixels the mesh covers whose offset is not negligible
  (``|d| >= IDENTITY_PX``); all others keep the input's value, bit for bit;
* :func:`warp_frame`: the input frame sampled once at those positions with a high-quality
  kernel, at full resolution (:func:`sample`: ``cv2.remap``'s bicubic or Lanczos-4, or a long
  windowed sinc, :mod:`.sinc_sampling`);
* :func:`feather_alpha`: the soft edge inside the deformed outline;
* :func:`fold_edges` and :func:`soften`: where the map jumps (the moved surface folds over
  itself or over the unmoved face, or squeezes the texture more than two to one) the sampled
  colours change abruptly from one pixel to the next; a small blur there anti-aliases the edge
  as a camera would.

Crops are (h, w, 3) uint8; masks (h, w) bool; offsets (h, w, 2) float32 pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

from .sinc_sampling import Upsampled, sample_sinc
from .source_map import UNCOVERED

IDENTITY_PX = 1.0e-3       # offsets shorter than this (pixels) leave the pixel as it is
FOLD_JUMP_PX = 1.0         # offset change between neighbours (pixels) that marks a fold
OPENCV_KERNELS = {"cubic": cv2.INTER_CUBIC, "lanczos": cv2.INTER_LANCZOS4, "linear": cv2.INTER_LINEAR}
INTERPOLATIONS = ("sinc", *OPENCV_KERNELS)   # the kernels :func:`sample` knows


def sample(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, interpolation: str = "cubic",
           upsampled: Upsampled | None = None) -> np.ndarray:
    """(h, w, 3) uint8: ``image`` (H, W, 3) uint8 sampled at (``map_x``, ``map_y``), (h, w)
    float32 pixels (outside the image: its edge pixels, replicated), with the kernel named
    ``interpolation`` (one of INTERPOLATIONS; the sinc through ``upsampled`` where it holds
    the part read: :func:`.sinc_sampling.sample_sinc`)."""
    if interpolation == "sinc":
        return sample_sinc(image, map_x, map_y, upsampled)
    return cv2.remap(image, map_x, map_y, OPENCV_KERNELS[interpolation], borderMode=cv2.BORDER_REPLICATE)


def covered_pixels(offsets: np.ndarray) -> np.ndarray:
    """(h, w) bool: the pixels some triangle of the deformed mesh drew."""
    return offsets[..., 0] < 0.5 * UNCOVERED


def changed_pixels(offsets: np.ndarray, identity_px: float = IDENTITY_PX) -> np.ndarray:
    """(h, w) bool: covered pixels whose offset is at least ``identity_px`` long (pixels)."""
    dx, dy = offsets[..., 0], offsets[..., 1]
    return (dx * dx + dy * dy >= identity_px * identity_px) & (dx < 0.5 * UNCOVERED)


def bounding_slices(mask: np.ndarray) -> tuple[slice, slice] | None:
    """(rows, cols) slices of the bounding box of ``mask`` (h, w) bool; None when it is empty."""
    x, y, w, h = cv2.boundingRect(mask.view(np.uint8))
    if w == 0 or h == 0:
        return None
    return slice(y, y + h), slice(x, x + w)


def source_positions(offsets: np.ndarray, origin: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Where each pixel p of a block samples the input, ``p + d(p)``: (map_x, map_y), (h, w)
    float32 frame pixels, from the block's ``offsets`` (h, w, 2) float32 (UNCOVERED pixels
    sample themselves) and ``origin``, the frame pixel (x, y) of its top-left pixel."""
    h, w = offsets.shape[:2]
    x0, y0 = origin
    covered = offsets[..., 0] < 0.5 * UNCOVERED
    map_x = np.where(covered, offsets[..., 0], np.float32(0.0))   # float32 throughout
    map_y = np.where(covered, offsets[..., 1], np.float32(0.0))
    map_x += np.arange(x0, x0 + w, dtype=np.float32)[None, :]
    map_y += np.arange(y0, y0 + h, dtype=np.float32)[:, None]
    return map_x, map_y


def warp_frame(frame: np.ndarray, offsets: np.ndarray, origin: tuple[int, int],
               interpolation: str = "cubic", upsampled: Upsampled | None = None,
               positions: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The input frame sampled at ``p + d(p)`` for each pixel p of a block.

    frame: (H, W, 3) uint8, the whole input frame (read around the block as the kernel needs,
    edge pixels replicated); offsets: (h, w, 2) float32 of the block, UNCOVERED pixels sample
    themselves; origin: the frame pixel (x, y) of the block's top-left pixel; interpolation:
    a key of INTERPOLATIONS (``upsampled``: :func:`sample`'s); positions: the block's
    :func:`source_positions` when already made. Returns (h, w, 3) uint8.
    """
    map_x, map_y = source_positions(offsets, origin) if positions is None else positions
    return sample(frame, map_x, map_y, interpolation, upsampled)


def feather_alpha(region: np.ndarray, width_px: float) -> np.ndarray:
    """(h, w) float32 alpha: 0 outside ``region`` (h, w) uint8 0/1, rising to 1 at ``width_px``
    pixels inside its outline (width 0: the region itself)."""
    if width_px <= 0:
        return region.astype(np.float32)
    alpha = cv2.distanceTransform(region, cv2.DIST_L2, 3)
    alpha *= 1.0 / width_px
    np.minimum(alpha, 1.0, out=alpha)
    return alpha


def sharpen_silhouette(alpha: np.ndarray, region: np.ndarray, feather_px: float, width_px: float) -> None:
    """A soft edge made narrower near ``region`` (h, w) uint8 0/1: ``alpha`` (h, w) float32 from
    :func:`feather_alpha` with ``feather_px`` becomes, within ``feather_px`` + 1 pixels of the
    region, the same distance over ``width_px`` (< ``feather_px``), in place. Beside what a face
    uncovered its outline is a silhouette, as sharp as a filmed one."""
    x, y, w, h = cv2.boundingRect(region)
    if w == 0:
        return
    r = int(np.ceil(feather_px)) + 1
    rows, cols = slice(max(0, y - r), y + h + r), slice(max(0, x - r), x + w + r)
    near = cv2.dilate(region[rows, cols], cv2.getStructuringElement(cv2.MORPH_RECT, (2 * r + 1, 2 * r + 1)))
    part = alpha[rows, cols]
    # alpha < 1 only within feather_px of the outline, where it is the distance over feather_px
    np.copyto(part, cv2.min(cv2.multiply(part, feather_px / width_px), 1.0), where=near.view(bool))


def fold_edges(offsets: np.ndarray, changed: np.ndarray, jump_px: float = FOLD_JUMP_PX) -> np.ndarray:
    """(h, w) bool: changed pixels next to a neighbour (right or below) that is covered and
    whose offset differs by more than ``jump_px`` pixels in x or y: both pixels are marked."""
    covered = covered_pixels(offsets)
    ox, oy = offsets[..., 0], offsets[..., 1]
    jx = (np.abs(ox[:, 1:] - ox[:, :-1]) > jump_px) | (np.abs(oy[:, 1:] - oy[:, :-1]) > jump_px)
    jx &= covered[:, 1:] & covered[:, :-1] & (changed[:, 1:] | changed[:, :-1])
    jy = (np.abs(ox[1:] - ox[:-1]) > jump_px) | (np.abs(oy[1:] - oy[:-1]) > jump_px)
    jy &= covered[1:] & covered[:-1] & (changed[1:] | changed[:-1])
    fold = np.zeros(changed.shape, bool)
    fold[:, 1:] |= jx
    fold[:, :-1] |= jx
    fold[1:] |= jy
    fold[:-1] |= jy
    return fold & changed


def soften(crop: np.ndarray, fold: np.ndarray, allowed: np.ndarray) -> None:
    """Blur ``crop`` (h, w, 3) uint8 in place across the ``fold`` pixels (h, w) bool: a 3x3
    Gaussian, faded in over one pixel around them, so the edge is anti-aliased, not smeared;
    only ``allowed`` (h, w) bool pixels are written."""
    near = bounding_slices(fold)
    if near is None:
        return
    # only around the folds (a few short edges, usually): two pixels for the weight's fade and
    # the blur's reach, one more so the blur reads the same pixels as on the whole crop
    h, w = fold.shape
    rows = slice(max(near[0].start - 3, 0), min(near[0].stop + 3, h))
    cols = slice(max(near[1].start - 3, 0), min(near[1].stop + 3, w))
    part = crop[rows, cols]
    weight = cv2.GaussianBlur(fold[rows, cols].astype(np.float32), (3, 3), 0)
    np.minimum(weight * 2.0, 1.0, out=weight)
    blurred = cv2.GaussianBlur(part, (3, 3), 0)
    mixed = cv2.blendLinear(blurred, part, weight, 1.0 - weight)
    np.copyto(part, mixed, where=((weight > 0) & allowed[rows, cols])[..., None])
