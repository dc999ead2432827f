"""Sampling an image at arbitrary positions through a windowed-sinc 2x upsampling: the
``sinc`` kernel of :mod:`.warp` (docs/architecture.md "Stages", 4).

A short kernel sampling between pixels (bicubic, even Lanczos-4) averages away the finest
detail of a video frame: skin pores, stubble, the sensor's grain. At half a pixel of shift no
4-tap kernel keeps much above half the Nyquist frequency, so a moved face looks softer than the
one beside it in the same video. A long windowed sinc keeps it, but ``cv2.remap`` offers none.

So the part of the image the positions read is first upsampled by two with a separable
windowed sinc (Lanczos, ``LOBES`` lobes; the image's own pixels are kept at the even positions,
the pixels in between are interpolated), then sampled once by ``cv2.remap`` with a bicubic kernel
at twice the coordinates. On the upsampled grid the image's detail lies below half its Nyquist
frequency, where the bicubic kernel passes it almost unchanged: together the two act as one
long interpolating kernel.

Images are (h, w, 3) uint8 BGR; positions (h', w') float32 pixels of the image.
"""

from __future__ import annotations

import cv2
import numpy as np

LOBES = 6        # of the Lanczos window: 2 * LOBES taps per interpolated pixel
MARGIN_PX = LOBES + 2   # image pixels read around the positions' bounding box (filter + bicubic support)


def half_sample_taps(lobes: int = LOBES) -> np.ndarray:
    """(2 * lobes,) float32: the Lanczos weights of the pixels -lobes+1 .. lobes around a point
    half a pixel past pixel 0, summing to one."""
    x = np.arange(-lobes + 1, lobes + 1) - 0.5
    taps = np.sinc(x) * np.sinc(x / lobes)
    return (taps / taps.sum()).astype(np.float32)


TAPS = half_sample_taps()   # made once: every frame's upsampling uses them


def upsample2x(image: np.ndarray, taps: np.ndarray | None = None) -> np.ndarray:
    """(2h, 2w, 3) uint8: ``image`` (h, w, 3) uint8 upsampled by two; its pixel (2y, 2x) is the
    image's pixel (y, x), the others are interpolated by the ``taps`` (:func:`half_sample_taps`)
    across, down, and both (default TAPS). Edge pixels are replicated."""
    taps = TAPS if taps is None else taps
    a = len(taps) // 2 - 1   # the anchor: the tap of the pixel just before the half-way point
    # four channels, so that a pixel is one uint32 and the interleaving below is one fast copy
    even = cv2.cvtColor(image, cv2.COLOR_BGR2BGRA)
    across = cv2.filter2D(even, -1, taps[None, :], anchor=(a, 0), borderType=cv2.BORDER_REPLICATE)
    h, w = image.shape[:2]
    up = np.empty((h, 2, 2 * w), np.uint32)   # row pairs: the even row, then the odd one below it
    up[:, 0, 0::2] = even.view(np.uint32)[..., 0]
    up[:, 0, 1::2] = across.view(np.uint32)[..., 0]
    # the odd rows: the even rows (the pixels and those across, interleaved) filtered down in one pass
    rows = up[:, 0].view(np.uint8).reshape(h, 2 * w, 4)
    up[:, 1] = cv2.filter2D(rows, -1, taps[:, None], anchor=(0, a), borderType=cv2.BORDER_REPLICATE).view(np.uint32)[..., 0]
    # back to three channels: the sampling after it costs a quarter less
    return cv2.cvtColor(up.view(np.uint8).reshape(2 * h, 2 * w, 4), cv2.COLOR_BGRA2BGR)


class Upsampled:
    """Part of an image upsampled by two once (:func:`upsample2x`), for more than one
    :func:`sample_sinc` at positions within it (e.g. a face and the background it uncovered).

    Upsampled(image, rect): ``image`` (H, W, 3) uint8; ``rect`` (x0, y0, x1, y1) frame pixels the
    positions lie in; the part taken is that grown by MARGIN_PX, cut to the image."""

    def __init__(self, image: np.ndarray, rect: tuple[int, int, int, int]):
        H, W = image.shape[:2]
        x0, y0, x1, y1 = (int(v) for v in rect)
        self.image = image
        self.x_lo, self.y_lo = min(max(x0 - MARGIN_PX, 0), W - 1), min(max(y0 - MARGIN_PX, 0), H - 1)
        self.x_hi, self.y_hi = min(max(x1 + MARGIN_PX, self.x_lo + 1), W), min(max(y1 + MARGIN_PX, self.y_lo + 1), H)
        self.up = upsample2x(np.ascontiguousarray(image[self.y_lo:self.y_hi, self.x_lo:self.x_hi]))

    def holds(self, image: np.ndarray, x_lo: int, y_lo: int, x_hi: int, y_hi: int) -> bool:
        """Whether this is ``image``'s and holds its part [x_lo, x_hi) x [y_lo, y_hi) (px)."""
        return (image is self.image and self.x_lo <= x_lo and self.y_lo <= y_lo
                and x_hi <= self.x_hi and y_hi <= self.y_hi)


def upsampled_over(image: np.ndarray, positions: list[tuple[np.ndarray, np.ndarray]]) -> Upsampled | None:
    """``image`` (H, W, 3) uint8 upsampled once where the ``positions`` read it, e.g. both a drag
    fill's and a face's: each (map_x, map_y) float32 arrays of one shape (pixels; empty ones
    ignored); the part taken is their bounding box as :func:`sample_sinc` grows it, so each of
    them is sampled through it exactly as through an upsampling of its own. None when all are empty."""
    lo, hi = [np.inf, np.inf], [-np.inf, -np.inf]
    for pos in positions:
        for k, m in enumerate(pos):
            if m.size:
                m_lo, m_hi, _, _ = cv2.minMaxLoc(m.reshape(m.shape[0], -1))
                lo[k], hi[k] = min(lo[k], m_lo), max(hi[k], m_hi)
    if not np.isfinite(lo[0]):
        return None
    return Upsampled(image, (int(np.floor(lo[0])), int(np.floor(lo[1])), int(np.ceil(hi[0])) + 1,
                             int(np.ceil(hi[1])) + 1))


def sample_sinc(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, upsampled: Upsampled | None = None
                ) -> np.ndarray:
    """(h', w', 3) uint8: ``image`` (H, W, 3) uint8 sampled at the positions (``map_x``,
    ``map_y``: (h', w') float32 pixels; outside the image the edge pixels are replicated), through
    the upsampled part of the image they read only: ``upsampled``'s when it holds that part
    (:class:`Upsampled`), else one made here."""
    H, W = image.shape[:2]
    (x_min, x_max, _, _), (y_min, y_max, _, _) = cv2.minMaxLoc(map_x), cv2.minMaxLoc(map_y)
    x_lo, x_hi = int(np.floor(x_min)) - MARGIN_PX, int(np.ceil(x_max)) + MARGIN_PX + 1
    y_lo, y_hi = int(np.floor(y_min)) - MARGIN_PX, int(np.ceil(y_max)) + MARGIN_PX + 1
    clamped = x_lo < 0 or y_lo < 0 or x_hi > W or y_hi > H
    x_lo, y_lo = min(max(x_lo, 0), W - 1), min(max(y_lo, 0), H - 1)
    x_hi, y_hi = min(max(x_hi, x_lo + 1), W), min(max(y_hi, y_lo + 1), H)
    if upsampled is not None and upsampled.holds(image, x_lo, y_lo, x_hi, y_hi):
        up, ox, oy = upsampled.up, upsampled.x_lo, upsampled.y_lo
    else:
        up, ox, oy = upsample2x(np.ascontiguousarray(image[y_lo:y_hi, x_lo:x_hi])), x_lo, y_lo
    ux, uy = map_x - np.float32(ox), map_y - np.float32(oy)
    if clamped:   # positions past the image's edge take its edge pixels, not the upsampled
        # grid's last row and column (half a pixel past the edge)
        np.clip(ux, x_lo - ox, x_hi - ox - 1, out=ux)
        np.clip(uy, y_lo - oy, y_hi - oy - 1, out=uy)
    ux *= 2.0
    uy *= 2.0
    return cv2.remap(up, ux, uy, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
