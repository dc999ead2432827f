"""A turned face's stretched surface by its outline mended from the face beside it (issue 51: the near jaw's light arc).

When a pose edit turns a face toward the camera, the side that the input saw at a grazing angle
is drawn larger: its pixels in the source map (backward offsets, output pixel -> input position)
span a fraction of an input pixel each, and those nearest the outline all read the input at the
fitted outline itself, where the input's pixels mix the face with what lies beside it (the wall,
the hair; anti-aliasing, blur and a fit a pixel or two off). Stretched over several output pixels
that mix is a pale (or dark) arc along the near cheek and jaw, and moving the sources inside only
stretches one column of skin into streaks: the input holds nothing of that surface. So those
pixels' colours are interpolated from the face's well-seen pixels around them (:func:`mend`), a
smooth continuation of the cheek, as the pose limit (:mod:`.pose_limit`) keeps such surface small.

Offsets are (h, w, 2) float32 pixels with :data:`.source_map.UNCOVERED` where no triangle is.
"""

from __future__ import annotations

import cv2
import numpy as np

from .motion_extension import pull_push, source_compression
from .source_map import UNCOVERED

#: Pixels nearer than this to the input's face outline (px) are the silhouette's mixed pixels.
SILHOUETTE_MARGIN_PX = 3.0
#: An output pixel spanning less than this many input pixels is stretched (the input saw it grazing).
STRETCHED = 0.5
#: The mending interpolates from the face within this many pixels of the mended ones.
MEND_CONTEXT_PX = 48


def signed_depth(region: np.ndarray) -> np.ndarray:
    """(h, w) float32: the distance (px) to the outline of ``region`` (h, w) uint8 0/1, positive
    inside, negative outside."""
    inside = cv2.distanceTransform(region, cv2.DIST_L2, 3)
    outside = cv2.distanceTransform((region == 0).view(np.uint8), cv2.DIST_L2, 3)
    return inside - outside


def unseen_by_silhouette(offsets: np.ndarray, face: np.ndarray, region: np.ndarray,
                         margin_px: float = SILHOUETTE_MARGIN_PX, stretched: float = STRETCHED) -> np.ndarray:
    """(h, w) bool: the ``face`` (h, w) bool pixels of the source map ``offsets`` (h, w, 2) float32
    that span fewer than ``stretched`` input pixels each, or are folded over
    (:func:`.motion_extension.source_compression`), or are next to one, and read the input within ``margin_px`` of the
    outline of its face ``region`` (h, w) uint8 0/1 (the same crop: where the face was before the
    edit) or outside it."""
    covered = offsets[..., 0] < 0.5 * UNCOVERED
    face = face & covered
    if not face.any() or not region.any():
        return np.zeros(face.shape, bool)
    ys, xs = np.nonzero(face)
    n, row = len(ys), 1024   # remap takes maps under 32767 a side: the points as rows of 1024
    sx = np.zeros(-(-n // row) * row, np.float32)
    sy = np.zeros_like(sx)
    sx[:n], sy[:n] = xs + offsets[ys, xs, 0], ys + offsets[ys, xs, 1]
    depth = cv2.remap(signed_depth(region), sx.reshape(-1, row), sy.reshape(-1, row), cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_REPLICATE).ravel()[:n]
    reads_outline = np.zeros(face.shape, bool)
    reads_outline[ys[depth < margin_px], xs[depth < margin_px]] = True
    grow = np.ones((3, 3), np.uint8)
    # stretched pixels, and their neighbours (a pixel whose right or lower neighbour is not covered has
    # no compression of its own), among those that read the input's outline
    near = face & (source_compression(offsets, covered, cv2.dilate(reads_outline.view(np.uint8), grow).view(bool))
                   < stretched)
    return cv2.dilate(near.view(np.uint8), grow).view(bool) & reads_outline


def mend(warped: np.ndarray, unseen: np.ndarray, face: np.ndarray) -> None:
    """``warped`` (h, w, 3) uint8, a face's sampled colours, with its ``unseen`` (h, w) bool pixels
    (:func:`unseen_by_silhouette`) replaced, in place, by a smooth interpolation of the other
    ``face`` (h, w) bool pixels' colours (:func:`.motion_extension.pull_push`), blended in over a
    pixel around them."""
    if not unseen.any():
        return
    known = (face & ~unseen).astype(np.float32)
    if not known.any():
        return
    x, y, w, h = cv2.boundingRect(unseen.view(np.uint8))   # the work on a box around them only
    r = MEND_CONTEXT_PX
    part = (slice(max(0, y - r), y + h + r), slice(max(0, x - r), x + w + r))
    filled = pull_push(warped[part].astype(np.float32), known[part])
    alpha = cv2.GaussianBlur(unseen[part].astype(np.float32), (3, 3), 0)[..., None] * face[part][..., None]
    warped[part] = np.clip(alpha * filled + (1.0 - alpha) * warped[part], 0, 255).astype(np.uint8)
