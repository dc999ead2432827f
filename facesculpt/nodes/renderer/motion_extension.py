"""The face's motion carried over the head around it, for pose edits (issue 18), and over a band
past its outline for shape edits (the compositor's ``outline_band``, issue 15: :func:`carry_past_outline`).

The face model ends at the forehead and the jaw; hair, ears and neck are not in it. When a pose
edit turns the head, the source map moves the face but not what surrounds it, which would tear
the head at the model's outline. This module extends the source map's offsets (backward: output
pixel -> input position) from the face over a *head region* (an ellipse around the face's box,
grown by ``HEAD_GROWTH`` of its sides: up for forehead and hair, sideways for the ears, down
for the neck) by pull-push interpolation, which continues the face's outline values smoothly,
and fades them to zero at the ellipse's border (smoothstep of the relative distance between the
face and the border), so the background beyond the head does not move: the seed's
"geometry-assisted warp of the surrounding regions".

Offsets are (h, w, 2) float32 pixels with :data:`.source_map.UNCOVERED` where no triangle is.
"""

from __future__ import annotations

import cv2
import numpy as np

from facesculpt.geometry import point_bounds

from .source_map import UNCOVERED

#: How far the head region reaches past the face's box: shares of its width (each side) and of its
#: height (up, down).
HEAD_GROWTH = {"side": 0.22, "up": 0.55, "down": 0.30}
#: The extension is interpolated on a grid this many pixels a cell, then resampled.
FIELD_STEP = 2
_SHIFT = 4


def _head_extent(pixels: np.ndarray) -> tuple[float, float, float, float]:
    """(left, top, right, bottom) frame px of the head region around the face at ``pixels`` (N, 2):
    their box grown by HEAD_GROWTH."""
    lo, hi = point_bounds(pixels)
    w, h = hi - lo
    return (lo[0] - HEAD_GROWTH["side"] * w, lo[1] - HEAD_GROWTH["up"] * h,
            hi[0] + HEAD_GROWTH["side"] * w, hi[1] + HEAD_GROWTH["down"] * h)


def head_box(pixels: np.ndarray, width: int, height: int) -> tuple[int, int, int, int] | None:
    """The frame rectangle (x0, y0, x1, y1) of the head region around the face at ``pixels``
    (N, 2) px (its vertices before and after the edit), cut to the ``width`` x ``height`` frame;
    None when less than 2 x 2 pixels of it are in the frame."""
    left, top, right, bottom = _head_extent(pixels)
    box = (max(0, int(np.floor(left))), max(0, int(np.floor(top))),
           min(width, int(np.ceil(right)) + 1), min(height, int(np.ceil(bottom)) + 1))
    return box if box[2] - box[0] >= 2 and box[3] - box[1] >= 2 else None


def head_region(shape: tuple[int, int], origin: tuple[int, int], pixels: np.ndarray) -> np.ndarray:
    """(h, w) uint8 0/1 the head region's ellipse on a crop of ``shape`` (h, w) whose top-left
    pixel is the frame pixel ``origin`` (x, y); ``pixels`` as in :func:`head_box` (not cut to the
    frame: the ellipse is the same whatever part of it the crop holds)."""
    left, top, right, bottom = _head_extent(pixels)
    centre = (0.5 * (left + right) - origin[0], 0.5 * (top + bottom) - origin[1])
    axes = (max(0.5 * (right - left), 1.0), max(0.5 * (bottom - top), 1.0))
    region = np.zeros(shape, np.uint8)
    f = 1 << _SHIFT  # cv2.ellipse takes sub-pixel coordinates as fixed point
    cv2.ellipse(region, (round(centre[0] * f), round(centre[1] * f)), (round(axes[0] * f), round(axes[1] * f)),
                0.0, 0.0, 360.0, 1, thickness=-1, lineType=cv2.LINE_8, shift=_SHIFT)
    return region


def pull_push(values: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(h, w, C) float32: a smooth interpolation of ``values`` (h, w, C) float32 known with
    ``weight`` (h, w) float32 in [0, 1] (0: unknown; pull: weighted averages down an image pyramid;
    push: each level's gaps filled from the coarser one). Pixels of weight 1 keep their values."""
    levels = [(values * weight[..., None], weight)]
    while min(levels[-1][1].shape) > 4:
        v, w = levels[-1]
        levels.append((cv2.pyrDown(v), cv2.pyrDown(w)))
    v, w = levels[-1]
    estimate = (v / np.maximum(w, 1e-6)[..., None]).astype(np.float32)
    for v, w in reversed(levels[:-1]):
        up = cv2.pyrUp(estimate, dstsize=(w.shape[1], w.shape[0]))
        if up.ndim == 2:
            up = up[..., None]
        own = v / np.maximum(w, 1e-6)[..., None]
        trust = np.minimum(w * 4.0, 1.0)[..., None]
        estimate = (trust * own + (1.0 - trust) * up).astype(np.float32)
    np.copyto(estimate, values, where=(weight >= 1.0)[..., None])
    return estimate


def _fade_out(u: np.ndarray) -> np.ndarray:
    """Smoothstep from 1 at ``u`` = 0 to 0 at ``u`` = 1 (``u`` in [0, 1])."""
    return 1.0 - u * u * (3.0 - 2.0 * u)


def extend_motion(offsets: np.ndarray, head: np.ndarray) -> np.ndarray:
    """The source map ``offsets`` (h, w, 2) float32 with the face's motion carried over the
    ``head`` (h, w) uint8 0/1 region (:func:`head_region`): its uncovered pixels get the
    interpolated offsets of the face (:func:`pull_push` on a grid ``FIELD_STEP`` times coarser: the
    motion of a turned head is smooth), faded from full at the face's outline to zero at the
    region's border. Covered pixels are unchanged, pixels outside both stay UNCOVERED. Returns a
    new (h, w, 2) float32 array."""
    covered = offsets[..., 0] < 0.5 * UNCOVERED
    if not covered.any():
        return offsets.copy()
    h, w = covered.shape
    small = (max(1, -(-w // FIELD_STEP)), max(1, -(-h // FIELD_STEP)))
    weight = cv2.resize(covered.astype(np.float32), small, interpolation=cv2.INTER_AREA)
    # (cv2.copyTo with a one-channel mask: numpy's broadcast where takes ten times as long)
    summed = cv2.resize(cv2.copyTo(offsets, covered.view(np.uint8), np.zeros_like(offsets)), small,
                        interpolation=cv2.INTER_AREA)
    mean = summed / np.maximum(weight, 1e-6)[..., None]   # each cell: the mean offset of its covered pixels
    # The fade is smooth too: distances and smoothstep on the grid, one resampling of the faded field.
    step = float(max(w, h)) / float(max(small))
    to_face = cv2.distanceTransform((weight < 0.5).view(np.uint8), cv2.DIST_L2, 3) * step
    to_edge = cv2.distanceTransform(cv2.resize(head, small, interpolation=cv2.INTER_NEAREST), cv2.DIST_L2, 3)
    to_edge = np.maximum(to_edge - 1.0, 0.0) * step  # zero a cell inside: resampled, it is zero at the border
    u = to_face / np.maximum(to_face + to_edge, 1e-6)
    fade = _fade_out(u)                          # 1 at the face, 0 at the border
    field = cv2.resize(pull_push(mean, weight) * fade[..., None], (w, h), interpolation=cv2.INTER_LINEAR)
    return cv2.copyTo(field, ((head != 0) & ~covered).view(np.uint8), offsets.copy())


def carry_past_outline(offsets: np.ndarray, outline: np.ndarray, reach_px: float,
                       gap: np.ndarray | None = None) -> np.ndarray:
    """The source map ``offsets`` (h, w, 2) float32 with a shape edit's motion carried ``reach_px``
    pixels past the ``outline`` region (h, w) uint8 0/1 (the original and the deformed face
    together): each uncovered pixel outside it within reach takes the offset of its nearest
    covered pixel (a distance transform with labels), faded by smoothstep from full at the
    outline to zero at ``reach_px``. ``gap`` (h, w) bool, optional: uncovered pixels inside the
    outline (what the face uncovered) that take their nearest covered pixel's offset too, unfaded
    (the drag fill: the background beside the face, carried in by its motion); other uncovered
    pixels inside the outline and those beyond reach stay UNCOVERED; covered pixels are unchanged.
    Cheaper than :func:`extend_motion` (no pyramid over the whole box), and a band a few pixels
    wide needs no smoother field than the outline's own. Returns a new (h, w, 2) float32 array."""
    out = offsets.copy()
    covered = offsets[..., 0] < 0.5 * UNCOVERED
    if (reach_px <= 0 and gap is None) or not cv2.countNonZero(covered.view(np.uint8)):
        return out
    to_outline = None
    target = np.zeros(covered.shape, bool)
    if reach_px > 0:
        to_outline = cv2.distanceTransform((outline == 0).view(np.uint8), cv2.DIST_L2, 5)
        target = (to_outline > 0) & (to_outline <= reach_px)
    if gap is not None:
        target |= gap & ~covered
    at = np.flatnonzero(target)   # the target pixels' flat indices, found once for the three reads below
    if len(at) == 0:
        return out
    _, nearest = cv2.distanceTransformWithLabels((~covered).view(np.uint8), cv2.DIST_L2, 5,
                                                 labelType=cv2.DIST_LABEL_PIXEL)
    # DIST_LABEL_PIXEL numbers the zero (covered) pixels from 1 in scan order
    carried = offsets.reshape(-1, 2)[np.flatnonzero(covered)[nearest.ravel()[at] - 1]]
    if to_outline is not None:
        u = to_outline.ravel()[at] / np.float32(reach_px)   # 0 in the gap: unfaded
        carried *= _fade_out(u)[:, None]
    out.reshape(-1, 2)[at] = carried
    return out
