"""What the renderer's window draws over the frame: text on a translucent panel, handles, ROI
and pinned vertices (docs/architecture.md "Stages", 4; the window itself is ``window.py``).

Plain functions of arrays (no window, no OpenGL), so they are tested on their own:

* :func:`draw_overlay` returns a copy of a (H, W, 3) uint8 BGR frame with text lines
  top-left, help lines bottom-left and the markers: handles (red rings), ROI (small blue
  dots), pins (yellow squares with a dark border);
* :func:`layout_text` places text lines so each fits inside the frame: the font scales with
  the frame's size, a line too wide is wrapped at its double spaces, then at single spaces,
  and a single word still too wide (a long path) keeps its end behind ``...``.

Text is white with a black rim around every letter, on a panel that darkens the frame behind
it, so it reads on black, white and busy frames alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

FONT = cv2.FONT_HERSHEY_SIMPLEX
MARGIN_PX = 6            # from the frame's edge to the panel's edge, and panel edge to text, px
PANEL_DARKEN = 0.6       # fraction of the frame's brightness the panel takes away
MIN_SCALE, MAX_SCALE = 0.4, 0.8   # cv2 font scales (0.5: letters about 10 px tall)
ELLIPSIS = "..."

TEXT_BGR = (255, 255, 255)
HANDLE_BGR = (0, 0, 255)         # red rings
ROI_BGR = (255, 200, 0)          # blue dots
PIN_BGR = (0, 215, 255)          # yellow squares
PIN_HALF_PX = 4                  # a pin is a (2 * 4 + 1) px square
OUTLINE_PX = 1                   # the dark rim around every letter, px


@dataclass(frozen=True)
class TextLine:
    """One line of text as it is drawn: ``org`` (x, y) the baseline's left end, px; ``width``,
    ``height`` (above the baseline) and ``baseline`` (below it) of the text from
    ``cv2.getTextSize``, px; ``scale`` and ``thickness`` of the font."""

    text: str
    org: tuple[int, int]
    width: int
    height: int
    baseline: int
    scale: float
    thickness: int


def text_scale(width: int, height: int) -> float:
    """The font scale for a frame of ``width`` x ``height`` px: 0.5 at 500 px, within 0.4–0.8."""
    return float(np.clip(min(width, height) / 1000.0, MIN_SCALE, MAX_SCALE))


def _text_width(text: str, scale: float, thickness: int) -> int:
    # The outline adds OUTLINE_PX on each side of the letters.
    return cv2.getTextSize(text, FONT, scale, thickness)[0][0] + 2 * OUTLINE_PX


def _keep_end(word: str, room: int, scale: float, thickness: int) -> str:
    """``word`` or ``...`` + its longest end that fits in ``room`` px."""
    if _text_width(word, scale, thickness) <= room:
        return word
    for start in range(1, len(word)):
        cut = ELLIPSIS + word[start:]
        if _text_width(cut, scale, thickness) <= room:
            return cut
    return ELLIPSIS


def _wrap(parts: list[str], sep: str, room: int, scale: float, thickness: int) -> list[str]:
    """Join ``parts`` with ``sep`` greedily into lines no wider than ``room`` px; a part wider
    than ``room`` is its own line (the caller splits it further)."""
    lines: list[str] = []
    for part in parts:
        if lines and _text_width(lines[-1] + sep + part, scale, thickness) <= room:
            lines[-1] += sep + part
        else:
            lines.append(part)
    return lines


def fit_lines(lines, room: int, scale: float, thickness: int = 1) -> list[str]:
    """``lines`` rewrapped so each is at most ``room`` px wide at this font: wrapped at double
    spaces, then at single spaces; a word still too wide keeps its end behind ``...``."""
    out: list[str] = []
    for line in lines:
        for group in _wrap([g.strip() for g in line.split("  ") if g.strip()], "  ", room, scale, thickness):
            for piece in _wrap(group.split(" "), " ", room, scale, thickness):
                out.append(_keep_end(piece, room, scale, thickness))
    return out


def layout_text(lines, width: int, height: int, *, bottom: bool = False) -> list[TextLine]:
    """Place ``lines`` inside a ``width`` x ``height`` px frame, top-left (``bottom``: the block
    ends at the frame's bottom). Every line fits between the panel margins; lines below the
    frame's bottom (a tiny frame) are left out."""
    scale = text_scale(width, height)
    thickness = 1
    room = width - 4 * MARGIN_PX
    fitted = fit_lines(lines, room, scale, thickness)
    (_, text_h), base = cv2.getTextSize("Wg", FONT, scale, thickness)
    text_h, base = text_h + OUTLINE_PX, base + OUTLINE_PX
    step = text_h + base + max(2, int(round(4 * scale)))
    top = 2 * MARGIN_PX
    if bottom:
        top = height - 2 * MARGIN_PX - step * len(fitted)
    placed = []
    for i, text in enumerate(fitted):
        y = top + step * i + text_h
        if y + base > height - MARGIN_PX or y - text_h < MARGIN_PX:
            continue
        (w, h), b = cv2.getTextSize(text, FONT, scale, thickness)
        placed.append(TextLine(text, (2 * MARGIN_PX, y), w + 2 * OUTLINE_PX, h + OUTLINE_PX, b + OUTLINE_PX,
                               scale, thickness))
    return placed


def draw_text(image: np.ndarray, placed: list[TextLine]) -> None:
    """Draw laid-out lines into ``image`` (H, W, 3) uint8 BGR, in place: a darkened panel
    around them, then white letters with a black rim: the letters' own mask grown by
    OUTLINE_PX (a thicker cv2.putText would not do: it advances each letter further, so its
    text drifts right of the thin one)."""
    if not placed:
        return
    x0 = MARGIN_PX
    y0 = max(0, min(t.org[1] - t.height for t in placed) - MARGIN_PX)
    x1 = min(image.shape[1], max(t.org[0] + t.width for t in placed) + MARGIN_PX)
    y1 = min(image.shape[0], max(t.org[1] + t.baseline for t in placed) + MARGIN_PX // 2)
    if x1 <= x0 or y1 <= y0:
        return
    panel = image[y0:y1, x0:x1]
    letters = np.zeros(panel.shape[:2], np.uint8)
    for t in placed:
        cv2.putText(letters, t.text, (t.org[0] + OUTLINE_PX - x0, t.org[1] - y0), FONT, t.scale, 255,
                    t.thickness, cv2.LINE_AA)
    size = 2 * OUTLINE_PX + 1
    rim = cv2.dilate(letters, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
    alpha = letters.astype(np.float32)[..., None] / 255.0
    dark = (1.0 - PANEL_DARKEN) * (1.0 - rim.astype(np.float32)[..., None] / 255.0)
    text = np.asarray(TEXT_BGR, np.float32)
    panel[:] = np.clip(panel * dark * (1.0 - alpha) + text * alpha + 0.5, 0, 255).astype(np.uint8)


def _pixels(points) -> list[tuple[int, int]]:
    if points is None or not len(points):
        return []
    p = np.asarray(points, np.float64).reshape(-1, 2)
    p = p[np.isfinite(p).all(axis=1)]
    return [(int(round(x)), int(round(y))) for x, y in p]


def draw_markers(image: np.ndarray, points=None, roi=None, pins=None) -> None:
    """Draw, in place into ``image`` (H, W, 3) uint8 BGR: ``roi`` (M, 2) px as small blue
    dots, ``pins`` (S, 2) px as yellow squares with a dark border, handle ``points`` (N, 2) px
    as red rings (on top). Non-finite points are skipped."""
    for x, y in _pixels(roi):
        cv2.circle(image, (x, y), 1, ROI_BGR, -1, cv2.LINE_AA)
    r = PIN_HALF_PX
    for x, y in _pixels(pins):
        cv2.rectangle(image, (x - r - 1, y - r - 1), (x + r + 1, y + r + 1), (0, 0, 0), -1)
        cv2.rectangle(image, (x - r, y - r), (x + r, y + r), PIN_BGR, -1)
    for x, y in _pixels(points):
        cv2.circle(image, (x, y), 5, HANDLE_BGR, 2, cv2.LINE_AA)


def draw_overlay(image: np.ndarray, lines=(), points=None, roi=None, pins=None, help_lines=()) -> np.ndarray:
    """A copy of ``image`` (H, W, 3) uint8 BGR with ``lines`` of text top-left, ``help_lines``
    bottom-left (left out when they would meet the top block), handle ``points`` ((N, 2)
    pixels, red rings), ``roi`` points ((M, 2) pixels, blue dots) and ``pins`` ((S, 2)
    pixels, yellow squares)."""
    out = image.copy()
    h, w = out.shape[:2]
    draw_markers(out, points, roi, pins)
    top = layout_text(list(lines), w, h)
    draw_text(out, top)
    if help_lines:
        bottom = layout_text(list(help_lines), w, h, bottom=True)
        top_end = max((t.org[1] + t.baseline for t in top), default=0) + 2 * MARGIN_PX
        if bottom and min(t.org[1] - t.height for t in bottom) - MARGIN_PX > top_end:
            draw_text(out, bottom)
    return out
