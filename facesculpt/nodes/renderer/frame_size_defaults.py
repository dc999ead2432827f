"""The live renderer's "auto" choices, by frame size.

From :data:`LARGE_FRAME_PIXELS` pixels a frame on, the renderer is what limits the live graph's
frame rate, so its "auto" settings trade a little quality for time there: the bicubic kernel
instead of the sinc (:func:`auto_interpolation`), no outline band (:func:`auto_outline_band`), and
a render mesh only as fine as the face's size on screen needs (:func:`auto_subdivision`, at every
size). Below it every path (window, graph, ``process``, demo) composites alike.
"""

from __future__ import annotations

import math

from .compositor_options import OUTLINE_BAND
from .subdivision import MAX_FINE_EDGE_PX

#: Frames with at least this many pixels (1280x720 and up) get the cheaper "auto" settings.
LARGE_FRAME_PIXELS = 1280 * 720
#: The largest outline band a renderer takes (share of the face's size).
MAX_OUTLINE_BAND = 0.5
#: From LARGE_FRAME_PIXELS on, "auto" subdivides the render mesh until its edges are this short on
#: screen, px (below it, until they are MAX_FINE_EDGE_PX short, as the compositor does by default).
AUTO_MAX_FINE_EDGE_PX = 8.0


def auto_interpolation(interpolation: str, width: int, height: int) -> str:
    """The kernel for frames of ``width`` x ``height`` pixels: ``interpolation`` itself, or for
    "auto" the sinc below :data:`LARGE_FRAME_PIXELS` pixels and the bicubic from there on."""
    if interpolation != "auto":
        return interpolation
    return "sinc" if width * height < LARGE_FRAME_PIXELS else "cubic"


def auto_outline_band(band: str | float, width: int, height: int) -> float:
    """The outline band (share of the face's size) for frames of ``width`` x ``height`` pixels:
    ``band`` itself (a number, or its text, in [0, MAX_OUTLINE_BAND]), or for "auto" the
    compositor's OUTLINE_BAND below :data:`LARGE_FRAME_PIXELS` pixels and 0 (no band) from there
    on. ValueError, in one sentence, for anything else."""
    if isinstance(band, str) and band.strip() == "auto":
        return OUTLINE_BAND if width * height < LARGE_FRAME_PIXELS else 0.0
    try:
        value = float(band)
    except (TypeError, ValueError):
        value = math.nan
    if not 0.0 <= value <= MAX_OUTLINE_BAND:
        raise ValueError(f"outline_band must be auto or a share of the face's size in [0, {MAX_OUTLINE_BAND}], "
                         f"got {band!r}")
    return value


def auto_subdivision(levels: str | int, width: int, height: int) -> tuple[int | None, float | None]:
    """The compositor's ``(subdivision, max_fine_edge_px)`` for frames of ``width`` x ``height``
    pixels: ``levels`` itself (0 to 3, a number or its text) with no edge limit, or for "auto"
    per frame as few levels as make the render mesh's edges on screen as long as the compositor's
    default (:data:`.subdivision.MAX_FINE_EDGE_PX`) below :data:`LARGE_FRAME_PIXELS` pixels and
    :data:`AUTO_MAX_FINE_EDGE_PX` from there on, within its triangle budget.
    ValueError, in one sentence, for anything else."""
    if isinstance(levels, str) and levels.strip() == "auto":
        return None, (MAX_FINE_EDGE_PX if width * height < LARGE_FRAME_PIXELS else AUTO_MAX_FINE_EDGE_PX)
    text = str(levels).strip()
    if text not in ("0", "1", "2", "3"):
        raise ValueError(f"subdivision must be auto or 0 to 3 levels, got {levels!r}")
    return int(text), None
