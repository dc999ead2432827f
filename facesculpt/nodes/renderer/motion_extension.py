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
"geometry-assisted warp of the surrounding regions". Where a turned face's outline folds away
from the camera under the hair (:func:`extend_behind_outline`), the extension starts inside the
face's soft edge and the face is blended over it (:func:`over_behind`), as an edit's outline is.

Offsets are (h, w, 2) float32 pixels with :data:`.source_map.UNCOVERED` where no triangle is.
"""

from __future__ import annotations

import cv2
import numpy as np

from facesculpt.geometry import point_bounds

from .source_map import UNCOVERED
from .warp import bounding_slices, warp_frame

#: How far the head region reaches past the face's box: shares of its width (each side) and of its
#: height (up, down).
HEAD_GROWTH = {"side": 0.22, "up": 0.55, "down": 0.30}
#: The extension is interpolated on a grid this many pixels a cell, then resampled.
FIELD_STEP = 2
#: An outline pixel of a turned face that spans more input pixels than this (the mesh folding away
#: from the camera: :func:`source_compression`) is not continued over the head (:func:`extend_behind_outline`).
FOLD_COMPRESSION = 3.0
#: A head goes on past the face model's outline (hair, temples, ears: no part of the model) down to
#: this share of the face's height from its top.
HEAD_GOES_ON = 0.5
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


def head_goes_on(shape: tuple[int, int], origin: tuple[int, int], pixels: np.ndarray) -> np.ndarray:
    """(h, w) bool on a crop of ``shape`` (h, w) whose top-left pixel is the frame pixel ``origin``
    (x, y): the rows where the head goes on past the outline of the face at ``pixels`` (V, 2) px
    (from the top of their box down ``HEAD_GOES_ON`` of its height: the forehead and temples)."""
    lo, hi = point_bounds(pixels)
    out = np.zeros(shape, bool)
    out[: max(0, int(lo[1] + HEAD_GOES_ON * (hi[1] - lo[1])) - origin[1])] = True
    return out


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


def _head_field(offsets: np.ndarray, seeds: np.ndarray, covered: np.ndarray, head: np.ndarray) -> np.ndarray:
    """(h, w, 2) float32: the offsets of the ``seeds`` (h, w) bool pixels interpolated over the
    whole crop (:func:`pull_push` on a grid ``FIELD_STEP`` times coarser), faded from full at the
    ``covered`` (h, w) bool face to zero at the border of the ``head`` (h, w) uint8 0/1 region."""
    h, w = covered.shape
    small = (max(1, -(-w // FIELD_STEP)), max(1, -(-h // FIELD_STEP)))
    weight = cv2.resize(seeds.astype(np.float32), small, interpolation=cv2.INTER_AREA)
    # (cv2.copyTo with a one-channel mask: numpy's broadcast where takes ten times as long)
    summed = cv2.resize(cv2.copyTo(offsets, seeds.view(np.uint8), np.zeros_like(offsets)), small,
                        interpolation=cv2.INTER_AREA)
    mean = summed / np.maximum(weight, 1e-6)[..., None]   # each cell: the mean offset of its seed pixels
    # The fade is smooth too: distances and smoothstep on the grid, one resampling of the faded field.
    step = float(max(w, h)) / float(max(small))
    face = weight if seeds is covered else cv2.resize(covered.astype(np.float32), small, interpolation=cv2.INTER_AREA)
    to_face = cv2.distanceTransform((face < 0.5).view(np.uint8), cv2.DIST_L2, 3) * step
    to_edge = cv2.distanceTransform(cv2.resize(head, small, interpolation=cv2.INTER_NEAREST), cv2.DIST_L2, 3)
    to_edge = np.maximum(to_edge - 1.0, 0.0) * step  # zero a cell inside: resampled, it is zero at the border
    u = to_face / np.maximum(to_face + to_edge, 1e-6)
    fade = _fade_out(u)                          # 1 at the face, 0 at the border
    return cv2.resize(pull_push(mean, weight) * fade[..., None], (w, h), interpolation=cv2.INTER_LINEAR)


def extend_motion(offsets: np.ndarray, head: np.ndarray) -> np.ndarray:
    """The source map ``offsets`` (h, w, 2) float32 with the face's motion carried over the
    ``head`` (h, w) uint8 0/1 region (:func:`head_region`): its uncovered pixels get the
    interpolated offsets of the face (:func:`pull_push` on a grid ``FIELD_STEP`` times coarser: the
    motion of a turned head is smooth), faded from full at the face's outline to zero at the
    region's border. Covered pixels are unchanged, pixels outside both stay UNCOVERED. Returns a
    new (h, w, 2) float32 array."""
    return extend_behind_outline(offsets, head, 0.0)[0]


def source_compression(offsets: np.ndarray, covered: np.ndarray, where: np.ndarray | None = None) -> np.ndarray:
    """(h, w) float32: how many input pixels each output pixel of the source map ``offsets``
    (h, w, 2) float32 spans (the determinant of the map p -> p + d(p), forward differences; 1: the
    input's own scale, above: a surface seen more foreshortened than in the input, below 0: folded
    over), 1 where a pixel or its right or lower neighbour is not ``covered`` (h, w) bool, and
    outside ``where`` (h, w) bool when given (only those pixels are computed)."""
    h, w = covered.shape
    det = np.ones((h, w), np.float32)
    ok = np.zeros((h, w), bool)
    ok[:-1, :-1] = covered[:-1, :-1] & covered[:-1, 1:] & covered[1:, :-1]
    if where is not None:
        ok &= where
    ys, xs = np.nonzero(ok)
    o = offsets[ys, xs]
    dx, dy = offsets[ys, xs + 1] - o, offsets[ys + 1, xs] - o   # d(offset)/dx, d(offset)/dy
    det[ys, xs] = (1.0 + dx[:, 0]) * (1.0 + dy[:, 1]) - dy[:, 0] * dx[:, 1]
    return det


def extend_behind_outline(offsets: np.ndarray, head: np.ndarray, inset_px: float,
                          goes_on: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`extend_motion` for a face whose outline, where it folds away from the camera, is
    composited with a soft edge ``inset_px`` pixels wide (0: none) over what lies behind it, as an
    edit's outline is over the background.

    Where the turned mesh folds away from the camera at its outline (its pixels within ``inset_px``
    of the outline span more than ``FOLD_COMPRESSION`` input pixels each: :func:`source_compression`)
    where the head goes on past the model's outline (``goes_on`` (h, w) bool, None: everywhere;
    the compositor's: the forehead and temples, hair and ears being no part of the model),
    continued outward its offsets would stretch a strip of the input at the fitted outline over the
    head (a dark streak at the temple): there the extension is interpolated from the face inside
    the soft edge and the face is blended over it. Elsewhere the outline (a true silhouette, or the
    model's edge where the head goes on, not folding) is continued as :func:`extend_motion` does. The face's own
    offsets are kept (its silhouette stays where the mesh draws it). Returns the extended offsets
    (h, w, 2) float32 and ``behind`` (h, w, 2) float32: the extension's field on the folded soft
    edge's pixels (what to blend the face's colour over there), UNCOVERED elsewhere; None when
    ``inset_px`` is 0 or no outline folds."""
    covered = offsets[..., 0] < 0.5 * UNCOVERED
    if not covered.any():
        return offsets.copy(), None
    seeds, band = covered, None
    if inset_px > 0:
        rim = covered & (cv2.distanceTransform(covered.view(np.uint8), cv2.DIST_L2, 3) <= inset_px)
        folded = rim & (source_compression(offsets, covered, rim) > FOLD_COMPRESSION)
        if goes_on is not None:
            folded &= goes_on
        if folded.any():
            r = int(np.ceil(inset_px))
            band = rim & cv2.dilate(folded.view(np.uint8), cv2.getStructuringElement(
                cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))).view(bool)
            seeds = covered & ~band
    field = _head_field(offsets, seeds, covered, head)
    out = cv2.copyTo(field, ((head != 0) & ~covered).view(np.uint8), offsets.copy())
    if band is None:
        return out, None
    behind = cv2.copyTo(field, band.view(np.uint8), np.full_like(offsets, UNCOVERED))
    return out, behind


def over_behind(warped: np.ndarray, frame: np.ndarray, behind: np.ndarray, alpha: np.ndarray,
                origin: tuple[int, int], interpolation: str) -> None:
    """The face composited over what lies behind its soft edge: ``warped`` (h, w, 3) uint8, the
    face's colours sampled for a block whose top-left pixel is the frame pixel ``origin`` (x, y),
    blended in place toward the ``frame`` (H, W, 3) uint8 sampled at ``behind`` (h, w, 2) float32
    offsets (:func:`extend_behind_outline`'s, UNCOVERED off the soft edge) by ``alpha`` (h, w)
    float32 (the face's share: the compositor's soft edge, 0 outside the face, 1 inside its width;
    :func:`.warp.feather_alpha`) where ``behind`` is given; ``interpolation`` as :func:`.warp.warp_frame`'s (the
    compositor's: the bicubic, since what lies behind is blended under the face's own colour)."""
    band = behind[..., 0] < 0.5 * UNCOVERED
    part = bounding_slices(band)
    if part is None:
        return
    rows, cols = part
    under = warp_frame(frame, behind[part], (origin[0] + cols.start, origin[1] + rows.start), interpolation)
    mine = warped[part]
    np.copyto(mine, cv2.blendLinear(mine, under, alpha[part], 1.0 - alpha[part]), where=band[part][..., None])


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
