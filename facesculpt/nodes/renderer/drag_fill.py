"""The drag fill (issue 16): what a shrinking face uncovers, taken from the background beside it
as the face's own motion carries it in.

When an edit pulls the outline in (cheeks, jaw), the pixels between the old and the new outline
show background the camera did not see in this frame. The compositor gives each of them the
source-map offset of its nearest pixel of the deformed face
(:func:`.motion_extension.carry_past_outline` with its ``gap``), so it samples the input as far
beyond the old outline as the outline moved there: the background next to the face, with its
edges and texture, continued into the gap (squeezed, as a 2D liquify would), instead of a smooth
smear; a real outline just past the fitted one (registration error) moves in with the face. A
pixel whose dragged source lands on the original face (where the motion runs along the outline,
not across it) is left to the smooth fill.

Crops (h, w, 3) uint8, masks (h, w), offsets (h, w, 2) float32 pixels (UNCOVERED: none).
"""

from __future__ import annotations

import cv2
import numpy as np

from .sinc_sampling import Upsampled
from .source_map import UNCOVERED
from .warp import sample

SMOOTH_PX = 3.0   # sigma (px) of the smoothing of the dragged offsets over the gap


def smooth_drag(dragged: np.ndarray, gap: np.ndarray, sigma_px: float = SMOOTH_PX) -> np.ndarray:
    """The ``dragged`` offsets (h, w, 2) float32 (UNCOVERED: none) with those of the ``gap`` pixels
    (h, w) bool replaced by a normalised smoothing (about a Gaussian of ``sigma_px``) of every set
    offset around them.

    Each gap pixel took its nearest face pixel's offset whole: a mosaic of constant patches. Where
    the strip shows the real outline (the fit lies a pixel or two inside it) the patches print it
    as a staircase, and their seams jump as the outline moves by a fraction of a pixel from frame
    to frame (flicker). Parts of the gap side by side are smoothed on boxes of their own (grown by
    three sigmas). Returns a new array (the same when nothing is set)."""
    known = dragged[..., 0] < 0.5 * UNCOVERED
    target = gap & known
    columns = np.flatnonzero(target.any(axis=0))
    if len(columns) == 0 or sigma_px <= 0:
        return dragged
    reach = int(np.ceil(3.0 * sigma_px))
    size = (2 * int(round(sigma_px)) + 1,) * 2
    # the strip's parts side by side (the two cheeks') each on its own box: far smaller than their common one
    out = dragged.copy()
    for run in np.split(columns, np.flatnonzero(np.diff(columns) > 2 * reach) + 1):
        used = np.flatnonzero(target[:, run[0]:run[-1] + 1].any(axis=1))
        rows = slice(max(used[0] - reach, 0), used[-1] + 1 + reach)
        cols = slice(max(run[0] - reach, 0), run[-1] + 1 + reach)
        k = known[rows, cols].astype(np.float32)
        block = dragged[rows, cols]
        stack = cv2.merge([block[..., 0] * k, block[..., 1] * k, k])   # offsets where set (else 0), where set
        # two box filters of 2 sigma + 1 px: nearly a Gaussian of sigma, at a cost that does not grow with it
        smooth = cv2.blur(cv2.blur(stack, size, borderType=cv2.BORDER_REPLICATE), size,
                          borderType=cv2.BORDER_REPLICATE)
        ys, xs = np.nonzero(target[rows, cols])
        out[ys + rows.start, xs + cols.start] = smooth[ys, xs, :2] / smooth[ys, xs, 2:3]
    return out


def dragged_to(dragged: np.ndarray, ys: np.ndarray, xs: np.ndarray, origin: tuple[int, int],
               shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the pixels (``ys``, ``xs``) (N,) of a box land, moved by their ``dragged`` offsets
    (h, w, 2), rounded: (x, y) (N,) int64 in an image of ``shape`` (H, W, ...) whose pixel (0, 0) is
    the box's pixel -``origin`` (x, y), and (N,) bool, inside it."""
    sx = np.rint(xs + origin[0] + dragged[ys, xs, 0]).astype(np.int64)
    sy = np.rint(ys + origin[1] + dragged[ys, xs, 1]).astype(np.int64)
    return sx, sy, (sx >= 0) & (sx < shape[1]) & (sy >= 0) & (sy < shape[0])


def lands_on(mask: np.ndarray, dragged: np.ndarray, ys: np.ndarray, xs: np.ndarray,
             origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """(N,) bool: whether the pixels (``ys``, ``xs``) (N,) of a box moved by their ``dragged`` offsets
    land on ``mask`` (non-zero), whose pixel (0, 0) is the box's pixel -``origin``
    (:func:`dragged_to`); positions outside ``mask`` do not."""
    sx, sy, inside = dragged_to(dragged, ys, xs, origin, mask.shape)
    hit = np.zeros(len(ys), bool)
    hit[inside] = mask[sy[inside], sx[inside]] != 0
    return hit


def dragged_positions(fill: np.ndarray, dragged: np.ndarray, origin: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Where the ``fill`` pixels (h, w, nonzero: to fill) of a box whose top-left pixel is ``origin``
    (x, y) with a set ``dragged`` offset (h, w, 2) may sample the frame: (x, y), each (N,) float32
    frame pixels, those :func:`drag_fill` samples among them."""
    ys, xs = np.nonzero((fill != 0) & (dragged[..., 0] < 0.5 * UNCOVERED))
    return ((xs + origin[0] + dragged[ys, xs, 0]).astype(np.float32),
            (ys + origin[1] + dragged[ys, xs, 1]).astype(np.float32))


def drag_fill(crop: np.ndarray, frame: np.ndarray, fill: np.ndarray, dragged: np.ndarray,
              face: np.ndarray, origin: tuple[int, int], interpolation: str = "cubic",
              upsampled: Upsampled | None = None) -> np.ndarray:
    """Fill the ``fill`` pixels (h, w, nonzero: to fill) of ``crop`` (the frame's box whose top-left
    pixel is ``origin`` (x, y); in place) with ``frame`` (H, W, 3) uint8 (the input) sampled at their
    ``dragged`` offsets, where those are set and do not land on ``face`` (h, w, nonzero: the face
    before and after the edit; positions outside the box count as background). Returns (h, w) bool,
    the pixels filled; the others are left as they were, for another fill. ``interpolation``,
    ``upsampled``: :func:`.warp.sample`'s."""
    done = (fill != 0) & (dragged[..., 0] < 0.5 * UNCOVERED)
    ys, xs = np.nonzero(done)
    if len(ys) == 0:
        return done
    on_face = lands_on(face, dragged, ys, xs)
    done[ys[on_face], xs[on_face]] = False
    keep = ~on_face
    ys, xs = ys[keep], xs[keep]
    if len(ys):  # only these pixels are sampled (the gaps are thin strips far apart, one per cheek),
        # as one row: remap works row by row, and a column of single pixels costs thirty times as much
        map_x = (xs + origin[0] + dragged[ys, xs, 0]).astype(np.float32)[None, :]
        map_y = (ys + origin[1] + dragged[ys, xs, 1]).astype(np.float32)[None, :]
        crop[ys, xs] = sample(frame, map_x, map_y, interpolation, upsampled)[0]
    return done
