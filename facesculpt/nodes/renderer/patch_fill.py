"""A fill that continues texture and structure: patch copying from the nearby background with a
smooth seam correction (docs/architecture.md "Stages", 4; issue 16).

The region is cut into square tiles (shifts are searched at half resolution, on grey). For each tile that holds pixels to fill, the background
around it (the known pixels of the tile grown by a rim) is matched against every shifted copy
of itself within a search radius (``cv2.matchTemplate``, sum of squared differences under the
known pixels' mask), among the shifts that put every pixel to fill on a known one; the best
shift (with a small penalty on its length, so near sources win ties) copies its pixels in. Tiles
overlap and are blended with tent weights. The copy is then corrected by a membrane: the
difference between the image and the copy on the known pixels around the hole, spread into it by
pull-push (:mod:`.inpaint`), is added, so the copy meets its surroundings without a seam and
carries the low frequencies of the border. Tiles whose surroundings are too little known, or
whose best match differs from them by more than ``MAX_MATCH_RMS``, keep the plain pull-push fill.

Images are (h, w, 3) uint8 BGR; masks (h, w) bool (set = True).
"""

from __future__ import annotations

import cv2
import numpy as np

from .pushpull import pushpull_into

TILE_PX = 16          # side of a tile, px (full resolution)
RIM_PX = 8            # known background matched around a tile, px
SEARCH_PX = 24        # how far a source may lie from its tile, px
OVERLAP_PX = 3        # a tile's copy reaches this far into its neighbours, blended, px
SHIFT_PENALTY = 0.05  # squared grey difference per pixel added per px^2 of shift (half resolution)
MAX_MATCH_RMS = 8.0   # a tile whose best match differs more (grey levels, RMS over its rim) keeps the smooth fill
MARGIN_PX = TILE_PX + RIM_PX + SEARCH_PX  # background a part's box needs around it


def _tent(n: int, ramp: int) -> np.ndarray:
    """(n,) float32 weights: 1 in the middle, falling linearly over ``ramp`` px at both ends, never 0."""
    i = np.arange(n, dtype=np.float32)
    return np.minimum(1.0, (np.minimum(i, n - 1 - i) + 1.0) / (ramp + 1.0)).astype(np.float32)


def best_shift(grey: np.ndarray, known: np.ndarray, fill: np.ndarray, win: tuple[int, int, int, int],
               search_px: int) -> tuple[int, int] | None:
    """The shift (dx, dy) px whose copy of the window ``win`` (x0, y0, x1, y1) of ``grey``
    ((h, w) float32) best matches its ``known`` pixels (squared differences), with every ``fill``
    pixel of the window landing on a known one; None when no shift qualifies or less than a
    quarter of the window is known, or when the best match differs from the window by more than
    ``MAX_MATCH_RMS`` (a copy that does not fit its surroundings). known, fill: (h, w) bool."""
    h, w = known.shape
    x0, y0, x1, y1 = win
    m_known = known[y0:y1, x0:x1]
    n_known = int(m_known.sum())
    if n_known < 0.25 * m_known.size:
        return None
    sx0, sy0 = max(0, x0 - search_px), max(0, y0 - search_px)
    sx1, sy1 = min(w, x1 + search_px), min(h, y1 + search_px)
    if sx1 - sx0 <= x1 - x0 or sy1 - sy0 <= y1 - y0:
        return None
    mask = m_known.astype(np.float32)
    ssd = cv2.matchTemplate(grey[sy0:sy1, sx0:sx1], np.ascontiguousarray(grey[y0:y1, x0:x1] * mask),
                            cv2.TM_SQDIFF, mask=mask)
    unknown = (~known[sy0:sy1, sx0:sx1]).astype(np.float32)
    holes = cv2.matchTemplate(unknown, fill[y0:y1, x0:x1].astype(np.float32), cv2.TM_CCORR)
    dy, dx = np.mgrid[sy0 - y0:sy1 - y1 + 1, sx0 - x0:sx1 - x1 + 1]
    cost = ssd / n_known + SHIFT_PENALTY * (dx * dx + dy * dy)
    cost[(holes > 0.5) | ~np.isfinite(cost)] = np.inf
    k = int(np.argmin(cost))
    if not np.isfinite(cost.flat[k]) or ssd.flat[k] / n_known > MAX_MATCH_RMS ** 2:
        return None
    return int(dx.flat[k]), int(dy.flat[k])


def _half(fill: np.ndarray, known: np.ndarray, image: np.ndarray):
    """Half-resolution grey image, known (all four pixels known) and fill (any of four) masks."""
    h, w = fill.shape
    size = ((w + 1) // 2, (h + 1) // 2)
    grey = cv2.resize(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), size, interpolation=cv2.INTER_AREA).astype(np.float32)
    k = cv2.resize(known.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.999
    f = cv2.resize(fill.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.0
    return grey, k & ~f, f


def patch_copy(image: np.ndarray, fill: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tiles' copies, blended: ((h, w, 3) float32 colours, (h, w) float32 weight; weight 0
    where no tile copied anything). Shifts are found at half resolution on grey, copies made at
    full resolution; copies cover the ``fill`` pixels and the known pixels beside them (for the
    seam correction); only known pixels are read."""
    h, w = fill.shape
    img = image.astype(np.float32)
    acc = np.zeros((h, w, 3), np.float32)
    wsum = np.zeros((h, w), np.float32)
    ys, xs = np.nonzero(fill)
    if len(ys) == 0:
        return acc, wsum
    grey, k2, f2 = _half(fill, known, image)
    t2, r2, s2 = TILE_PX // 2, RIM_PX // 2, SEARCH_PX // 2
    h2, w2 = f2.shape
    for ty in range(int(ys.min()) // 2 // t2 * t2, int(ys.max()) // 2 + 1, t2):
        for tx in range(int(xs.min()) // 2 // t2 * t2, int(xs.max()) // 2 + 1, t2):
            if not f2[ty:ty + t2, tx:tx + t2].any():
                continue
            win = (max(0, tx - r2), max(0, ty - r2), min(w2, tx + t2 + r2), min(h2, ty + t2 + r2))
            shift = best_shift(grey, k2, f2, win, s2)
            if shift is None:
                continue
            dx, dy = 2 * shift[0], 2 * shift[1]
            o = OVERLAP_PX
            gx0, gy0 = max(0, 2 * tx - o, -dx), max(0, 2 * ty - o, -dy)
            gx1, gy1 = min(w, 2 * (tx + t2) + o, w - dx), min(h, 2 * (ty + t2) + o, h - dy)
            if gx1 <= gx0 or gy1 <= gy0:
                continue
            src = (slice(gy0 + dy, gy1 + dy), slice(gx0 + dx, gx1 + dx))
            wt = np.outer(_tent(gy1 - gy0, 2 * o), _tent(gx1 - gx0, 2 * o)) * known[src]
            acc[gy0:gy1, gx0:gx1] += img[src] * wt[..., None]
            wsum[gy0:gy1, gx0:gx1] += wt
    done = wsum > 0
    acc[done] /= wsum[done][:, None]
    return acc, wsum


def fill_patch(image: np.ndarray, fill: np.ndarray, known: np.ndarray, smooth: np.ndarray) -> np.ndarray:
    """The patch fill of the ``fill`` pixels of ``image`` from the ``known`` pixels: (h, w, 3)
    uint8 colours (meaningful at ``fill`` only). ``smooth`` (h, w, 3) uint8 is the pull-push fill
    of the same region, kept where no tile found a source; its pull-push pyramid also spreads the
    seam correction (:func:`spread`)."""
    fill = np.asarray(fill, bool)
    known = np.asarray(known, bool) & ~fill
    copy, wsum = patch_copy(image, fill, known)
    copied = fill & (wsum > 0)
    if not copied.any():
        return smooth
    # The seam correction: image - copy on the known pixels the copy covers, spread by pull-push.
    ring = known & (wsum > 0)
    out = smooth.astype(np.float32)
    if ring.any():
        diff = np.clip(image.astype(np.float32) - copy + 128.0, 0, 255).astype(np.uint8)
        spread = np.zeros_like(diff)
        pushpull_into(spread, diff, copied, ring)
        corrected = copy + spread.astype(np.float32) - 128.0
    else:
        corrected = copy
    out[copied] = corrected[copied]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)
