"""The inside of a mouth that opens wider than the frame it is rendered from ever showed.

The compositor takes every colour from the input frame; where a closed mouth is made to open, the
frame holds only lips there, and the warp would stretch them across the gap. This paints the gap
instead: a dark interior (the lips' own colour darkened, so it suits the face's lighting) with a
soft, light band under the upper lip (teeth, blurred: no individual teeth are invented), blended in
with a feathered edge, and only as far as the rendered opening is wider than the source's own.
"""

from __future__ import annotations

import cv2
import numpy as np

#: MediaPipe face-mesh vertices of the inner lip line, in order around the mouth (upper lip from
#: the right corner 78 to the left corner 308, then the lower lip back).
INNER_LIP_FACEMESH: tuple[int, ...] = (78, 191, 80, 81, 82, 13, 312, 311, 310, 415, 308,
                                       324, 318, 402, 317, 14, 87, 178, 88, 95)
#: A source mouth whose inner lips are less than this far apart (px, :func:`opening_px`) is closed:
#: the frame holds no interior to stretch, so an opening the edit makes is painted.
CLOSED_MOUTH_PX = 3.0
#: How dark the interior is: a share of the lips' mean colour.
INTERIOR_SHADE = 0.25
#: The teeth band: its colour (BGR), height as a share of the opening's mean height, width as a
#: share of the opening's width (centred, fading out toward the corners).
TEETH_BGR = (168, 178, 186)
TEETH_SHARE = 0.3
TEETH_WIDTH = 0.7


def opening_px(polygon_px: np.ndarray) -> float:
    """The opening of an inner-lip polygon (N, 2) pixels, upper lip first then lower (as
    :data:`INNER_LIP_FACEMESH`): its area divided by its width (px), 0 when closed."""
    p = np.asarray(polygon_px, np.float64)
    if len(p) < 3 or not np.isfinite(p).all():
        return 0.0
    width = float(np.ptp(p[:, 0]))
    area = 0.5 * abs(float(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(p[:, 1], np.roll(p[:, 0], -1))))
    return area / width if width > 1e-6 else 0.0


def paint_mouth_interior(image: np.ndarray, polygon_px: np.ndarray, source_opening_px: float,
                         lip_bgr: np.ndarray | None = None) -> np.ndarray:
    """``image`` (H, W, 3) uint8 BGR with the mouth opening ``polygon_px`` (N, 2) pixels (the
    rendered inner lips, upper lip first) painted as a dark interior with a soft teeth band under
    the upper lip. The paint's opacity grows from 0, where the rendered opening (:func:`opening_px`)
    is no wider than ``source_opening_px`` (what the source frame shows of its own mouth, px), to 1
    at 4 px wider. lip_bgr: (3,) the lips' colour (None: sampled around the polygon). Returns a
    new image; the input is not modified."""
    out = image.copy()
    poly = np.asarray(polygon_px, np.float64)
    extra = opening_px(poly) - float(source_opening_px)
    opacity = float(np.clip(extra / 4.0, 0.0, 1.0))
    if opacity <= 0.0:
        return out
    h, w = image.shape[:2]
    x0, y0 = np.floor(poly.min(0)).astype(int) - 8
    x1, y1 = np.ceil(poly.max(0)).astype(int) + 8
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return out
    crop = out[y0:y1, x0:x1].astype(np.float32)
    local = np.round((poly - (x0, y0)) * 4).astype(np.int32)  # 2 fractional bits
    mask = np.zeros(crop.shape[:2], np.uint8)
    cv2.fillPoly(mask, [local], 255, lineType=cv2.LINE_AA, shift=2)
    if lip_bgr is None:
        ring = cv2.dilate(mask, np.ones((5, 5), np.uint8)) > 0
        ring &= mask == 0
        lip_bgr = crop[ring].mean(0) if ring.any() else np.array([60.0, 60.0, 120.0])
    fill = np.empty_like(crop)
    fill[:] = np.asarray(lip_bgr, np.float32) * INTERIOR_SHADE
    # The teeth band: under the upper lip, a share of the opening's height, its lower edge soft.
    n = len(poly)
    upper = poly[: n // 2 + 1] - (x0, y0)
    cols = np.arange(crop.shape[1], dtype=np.float64)
    order = np.argsort(upper[:, 0])
    top = np.interp(cols, upper[order, 0], upper[order, 1])
    height = max(opening_px(poly) * TEETH_SHARE, 1.0)
    rows = np.arange(crop.shape[0], dtype=np.float64)[:, None]
    teeth = np.clip((top[None, :] + height - rows) / max(height * 0.6, 1.0), 0.0, 1.0)
    centre, half = (upper[:, 0].max() + upper[:, 0].min()) / 2, max(np.ptp(upper[:, 0]) * TEETH_WIDTH / 2, 1.0)
    teeth = teeth * np.clip((half - np.abs(cols - centre)) / (0.4 * half), 0.0, 1.0)[None, :] * 0.8
    fill = fill * (1 - teeth[..., None]) + np.asarray(TEETH_BGR, np.float32) * teeth[..., None]
    fill = cv2.GaussianBlur(fill, (0, 0), 1.5)
    alpha = cv2.GaussianBlur(mask.astype(np.float32) / 255.0, (0, 0), 1.0)[..., None] * opacity
    out[y0:y1, x0:x1] = np.clip(crop * (1 - alpha) + fill * alpha + 0.5, 0, 255).astype(np.uint8)
    return out


def paint_opened_mouth(image: np.ndarray, source_px: np.ndarray, rendered_px: np.ndarray,
                       keep_mask: np.ndarray | None = None) -> np.ndarray:
    """``image`` (H, W, 3) uint8 BGR with the mouth painted (:func:`paint_mouth_interior`) where a
    face-mesh face whose mouth is closed in the frame (its projected vertices ``source_px`` (468, 2)
    px, inner lips under :data:`CLOSED_MOUTH_PX` apart) is rendered open (``rendered_px`` (468, 2)
    px, the deformed vertices). A frame that shows its own open mouth, or another mesh, is returned
    as it is. ``keep_mask`` (H, W) bool: pixels left as ``image`` has them (a hand in front)."""
    src, dst = np.asarray(source_px), np.asarray(rendered_px)
    if len(src) != 468 or len(dst) != 468:
        return image
    lips = np.asarray(INNER_LIP_FACEMESH)
    source_opening = opening_px(src[lips])
    if source_opening >= CLOSED_MOUTH_PX:
        return image
    out = paint_mouth_interior(image, dst[lips], source_opening)
    if keep_mask is not None:
        out[keep_mask] = image[keep_mask]
    return out
