"""The head's motion carried down over the neck and the body below the jaw (issue 51), for decoding
a coded talking head.

A coded stream sends one keyframe; every frame moves its fitted face. :mod:`.motion_extension`
carries the face's motion over the head around it (hair, ears, the top of the neck) and fades it to
zero at an ellipse around the head, so the keyframe's neck and shoulders stay still while the head
moves: the neck is stretched between the moving chin and the still body, and the background beside
it is smeared into pale streaks, and the jaw's opening drags the neck with it. Here the head's
motion at the top of its neck (:func:`neck_motion`: the rigid motion of the face's upper part, so
the jaw's opening does not move the body, at a point behind the chin, so a nod moves it little; its
sideways part) is blended into the body below the jaw: fully in a body core (the neck, widening
into the shoulders) just below the chin, fading by smoothstep over a wide margin beside the core
and over ``BODY_REACH`` face heights down (the shoulders sway less than the neck), so the
background beside the body is bent smoothly, never torn. The blend weight rises from zero near the
chin, so the face's own field and the head's extension (:func:`.motion_extension.extend_motion`)
are kept above the jaw and joined continuously below it.

Offsets are (h, w, 2) float32 pixels of a source map (backward: output pixel -> input position)
with :data:`.source_map.UNCOVERED` where no triangle is.
"""

from __future__ import annotations

import numpy as np

from facesculpt.geometry import point_bounds
from facesculpt.geometry.similarity import similarity_procrustes

from .camera import project
from .source_map import UNCOVERED

#: The body core's half width at the chin, as a share of the face's width (the neck).
NECK_HALF_WIDTH = 0.35
#: How fast the core widens below the chin: extra half width per pixel down (the shoulders).
SHOULDER_SLOPE = 0.9
#: Width of the fade beside the core, as a share of the face's width.
SIDE_FADE = 0.6
#: The chin: the face's vertices within this share of its height above its lowest one.
CHIN_ROWS = 0.12
#: The head's rigid part: the face's vertices within this share of its height below its highest one.
RIGID_PART = 0.6
#: The body follows the head fully at the chin, fading by smoothstep to nothing this many face
#: heights below it (the shoulders follow the head's sway less than the neck).
BODY_REACH = 1.5
#: The neck point lies this share of the face's largest extent behind its chin.
NECK_DEPTH = 0.35
#: The share of the neck point's vertical motion the body takes: the neck absorbs a nod and the
#: jaw's drop, the shoulders do not rise and fall with the head.
BODY_VERTICAL = 0.0
#: Where the blend starts, as a share of the face's height above its lowest point (negative: below
#: it; the skin just under the jaw moves with the jaw, as the head's extension carries it).
BLEND_START = -0.1
#: The blend's rise from nothing to full, as a share of the face's height.
BLEND_LENGTH = 0.3


def body_box(pixels: np.ndarray, width: int, height: int) -> tuple[int, int, int, int] | None:
    """The frame rectangle (x0, y0, x1, y1) the body's motion reaches for a face at ``pixels``
    (N, 2) px (its vertices before and after the motion): from the blend's start down to the
    frame's bottom, as wide as the core at the bottom plus its fade, cut to the ``width`` x
    ``height`` frame; None when less than 2 x 2 pixels of it are in the frame."""
    lo, hi = point_bounds(pixels)
    w, h = hi - lo
    cx = 0.5 * (lo[0] + hi[0])
    reach = BODY_REACH * h
    half = NECK_HALF_WIDTH * w + SHOULDER_SLOPE * reach + SIDE_FADE * w
    box = (max(0, int(np.floor(cx - half))), max(0, int(np.floor(hi[1] - BLEND_START * h))),
           min(width, int(np.ceil(cx + half)) + 1), min(height, int(np.ceil(hi[1] + reach)) + 1))
    return box if box[2] - box[0] >= 2 and box[3] - box[1] >= 2 else None


def union_box(a, b):
    """The smallest rectangle (x0, y0, x1, y1) holding both rectangles (either may be None)."""
    if a is None or b is None:
        return a if b is None else b
    return min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])


def _smoothstep(u: np.ndarray) -> np.ndarray:
    """0 at ``u`` <= 0, 1 at ``u`` >= 1, smooth between."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def body_weight(shape: tuple[int, int], origin: tuple[int, int], face_box: tuple[float, float, float, float],
                chin_x: float) -> np.ndarray:
    """(h, w) float32 in [0, 1]: how much of the body's motion each pixel of a crop of ``shape``
    (h, w), whose top-left pixel is the frame pixel ``origin`` (x, y), takes: smoothstep from 0 at
    ``BLEND_START`` of the face's height above its lowest point (negative: below) to 1
    ``BLEND_LENGTH`` of it further down, times 1 in the body
    core around ``chin_x`` (frame px; ``NECK_HALF_WIDTH`` of the face's width, widening by
    ``SHOULDER_SLOPE`` per pixel below the chin), falling by smoothstep to 0 over ``SIDE_FADE`` of
    the face's width beside it, and by smoothstep from 1 at the face's lowest point to 0
    ``BODY_REACH`` face heights below it. ``face_box``: (left, top, right, bottom) frame px of the face."""
    left, top, right, bottom = (float(v) for v in face_box)
    chin_x = float(chin_x)
    fw, fh = max(right - left, 1.0), max(bottom - top, 1.0)
    ys = np.arange(shape[0], dtype=np.float32)[:, None] + np.float32(origin[1])
    xs = np.arange(shape[1], dtype=np.float32)[None, :] + np.float32(origin[0])
    vertical = _smoothstep((ys - (bottom - BLEND_START * fh)) / (BLEND_LENGTH * fh))
    vertical *= _smoothstep(1.0 - (ys - bottom) / (BODY_REACH * fh))
    half = NECK_HALF_WIDTH * fw + SHOULDER_SLOPE * np.maximum(ys - bottom, 0.0)
    lateral = _smoothstep(1.0 - (np.abs(xs - chin_x) - half) / (SIDE_FADE * fw))
    return (vertical * lateral).astype(np.float32)


def neck_motion(fitted: np.ndarray, projected: np.ndarray, deformed: np.ndarray, P: np.ndarray) -> np.ndarray:
    """(2,) float64 px: the head's motion at the top of its neck, as a source-map offset (output
    pixel -> input pixel). The similarity that best maps the ``fitted`` (V, 3) camera-space
    vertices of the face's upper part (within ``RIGID_PART`` of its height from the top of its
    ``projected`` (V, 2) px: forehead, eyes, nose; the jaw's opening is not the head's motion)
    onto the ``deformed`` (V, 3) ones moves the neck point (below the chin's vertices,
    ``NECK_DEPTH`` of the face's largest extent behind them, along the face's thinnest axis away
    from the camera); the offset is its pixel under ``P`` (3, 4) before minus after, its vertical
    part scaled by ``BODY_VERTICAL``. A nod turns the head about that point, so it moves the body
    little; a sway moves both."""
    top, bottom = projected[:, 1].min(), projected[:, 1].max()
    upper = projected[:, 1] <= top + RIGID_PART * (bottom - top)
    s, R, t = similarity_procrustes(fitted[upper], deformed[upper])
    centred = fitted - fitted.mean(axis=0)
    _, sv, axes = np.linalg.svd(centred, full_matrices=False)
    chin = fitted[projected[:, 1] >= bottom - CHIN_ROWS * (bottom - top)].mean(axis=0)
    step = NECK_DEPTH * float(np.ptp(centred @ axes[0])) * axes[2]
    _, depth = project(P, np.stack([chin + step, chin - step]))
    neck = chin + step if depth[0] > depth[1] else chin - step
    px, _ = project(P, np.stack([neck, s * R @ neck + t]))
    return (px[0] - px[1]) * np.array([1.0, BODY_VERTICAL])


def carry_to_body(offsets: np.ndarray, face: np.ndarray, origin: tuple[int, int], dst_px: np.ndarray,
                  motion: np.ndarray) -> np.ndarray:
    """The source map ``offsets`` (h, w, 2) float32 (the head's motion already carried over the
    head: :func:`.motion_extension.extend_motion`) with the body's ``motion`` (2,) px (an offset:
    :func:`neck_motion`) blended into the body below the jaw of the face at the output pixels
    ``dst_px`` (V, 2) frame px: each pixel not in the
    ``face`` (h, w) bool (the covered pixels of the face itself, kept as they are) becomes
    (1 - b) * its offset + b * that motion, with b of :func:`body_weight` (UNCOVERED offsets count
    as zero). ``origin``: the crop's top-left frame pixel (x, y). Returns a new (h, w, 2) float32
    array; a copy when fewer than 3 vertices are given."""
    out = offsets.copy()
    if len(dst_px) < 3:
        return out
    lo, hi = point_bounds(dst_px)
    chin = dst_px[dst_px[:, 1] >= hi[1] - CHIN_ROWS * (hi[1] - lo[1])].mean(axis=0)
    r0 = int(np.clip(np.floor(hi[1] - BLEND_START * (hi[1] - lo[1])) - origin[1], 0, out.shape[0]))
    b = body_weight((out.shape[0] - r0, out.shape[1]), (origin[0], origin[1] + r0), (lo[0], lo[1], hi[0], hi[1]),
                    float(chin[0]))   # zero above row r0
    b[face[r0:]] = 0.0
    cols = np.flatnonzero(b.max(axis=0, initial=0.0) > 1e-3)
    if len(cols) == 0:
        return out
    b = b[:, cols[0]:cols[-1] + 1]
    part = out[r0:, cols[0]:cols[-1] + 1]   # a view: written in place
    known = np.where(part[..., :1] < 0.5 * UNCOVERED, part, np.float32(0.0))
    blended = known + b[..., None] * (np.asarray(motion, np.float32) - known)
    reach = b > 1e-3
    part[reach] = blended[reach]
    return out
