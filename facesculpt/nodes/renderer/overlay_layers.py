"""Which layers the renderer's window draws over the frame (its ``overlay`` parameter), and the
drawing of those that describe a face: plain functions of arrays (no window, no OpenGL).

:data:`OVERLAYS` names every layer with its help; :func:`parse_overlay` reads the parameter (a
comma list such as ``info,expression``; ``true`` is ``info``, as the parameter was a switch
before; ``false``, ``off``, ``none`` or empty: nothing) and refuses an unknown name in one sentence.
:data:`DRAWERS` maps a face layer's name to its function ``draw(image, box, message, K) -> image``
(``box`` the face's (x0, y0, x1, y1) pixels, ``message`` the layer's newest message for that
face, ``K`` (3, 3) the frame's intrinsics or None).
"""

from __future__ import annotations

import cv2
import numpy as np

from .gaze_overlay import draw_gaze
from .overlay import FONT, OUTLINE_PX, TEXT_BGR

#: Layer name -> what it draws.
OVERLAYS: dict[str, str] = {
    "info": "fps, stage times, handles, ROI, pins and the key help",
    "expression": "the expression recognised (face/expression) above each face, with its intensity",
    "gaze": "the gaze ray of each eye (face/gaze: the landmarks node's irises=true)",
}
#: The ``overlay`` parameter's default and help (declared here, beside the layers).
OVERLAY_DEFAULT = "info"
OVERLAY_HELP = ("window layers, a comma list of " + "; ".join(f"{k}: {v}" for k, v in OVERLAYS.items())
                + " (true: info; false: none)")
_NONE = ("", "false", "off", "none", "no", "0")
_INFO = ("true", "on", "yes", "1")

#: Expression label -> its colour (BGR) in the window.
EXPRESSION_BGR: dict[str, tuple[int, int, int]] = {
    "neutral": (200, 200, 200), "happiness": (80, 220, 80), "surprise": (60, 220, 240), "sadness": (230, 150, 60),
    "anger": (60, 60, 240), "disgust": (60, 160, 120), "fear": (200, 90, 200),
}


def parse_overlay(value) -> frozenset[str]:
    """The layers named by ``value`` (bool, or a comma list of :data:`OVERLAYS` names); ValueError
    in one sentence for an unknown name."""
    if isinstance(value, bool):
        return frozenset({"info"}) if value else frozenset()
    text = str(value).strip().lower()
    if text in _NONE:
        return frozenset()
    if text in _INFO:
        return frozenset({"info"})
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in OVERLAYS]
    if unknown:
        raise ValueError(f"overlay {_unknown_text(unknown)}")
    return frozenset(names)


def _unknown_text(unknown: list[str]) -> str:
    return (f"names an unknown layer: {', '.join(unknown)} (the layers: {', '.join(OVERLAYS)}, "
            f"as a comma list)")


def overlay_problem(value) -> str:
    """Why ``value`` is not an ``overlay`` (the end of a sentence, as a parameter's check says it);
    "" when it is."""
    try:
        parse_overlay(value)
    except ValueError as exc:
        return str(exc).removeprefix("overlay ")
    return ""


def face_box(projected: np.ndarray, width: int, height: int) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) the bounding box of a face's projected vertices (V, 2) pixels, clipped to
    the frame; None when none of them is finite."""
    p = np.asarray(projected, np.float64).reshape(-1, 2)
    p = p[np.isfinite(p).all(axis=1)]
    if not len(p):
        return None
    x0, y0 = np.clip(p.min(axis=0), 0, [width - 1, height - 1])
    x1, y1 = np.clip(p.max(axis=0), 0, [width - 1, height - 1])
    return int(x0), int(y0), int(x1), int(y1)


def expression_text(label: str, intensity: float, phase: str = "") -> str:
    """The words the window shows for a recognised expression, e.g. ``happiness 70 %``."""
    if not label:
        return ""
    return label if label == "neutral" else f"{label} {100 * float(intensity):.0f} %"


def _rimmed_text(image: np.ndarray, text: str, org: tuple[int, int], scale: float, colour) -> None:
    """Draw ``text`` at ``org`` (baseline's left end, px) into ``image`` in place, in ``colour``
    with a black rim: the letters' mask grown by OUTLINE_PX, as overlay.draw_text does (a thicker
    putText would advance each letter further)."""
    letters = np.zeros(image.shape[:2], np.uint8)
    cv2.putText(letters, text, org, FONT, scale, 255, 1, cv2.LINE_AA)
    size = 2 * OUTLINE_PX + 1
    rim = cv2.dilate(letters, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
    ys, xs = np.nonzero(rim)
    if not len(ys):
        return
    sl = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
    alpha = letters[sl].astype(np.float32)[..., None] / 255.0
    keep = 1.0 - rim[sl].astype(np.float32)[..., None] / 255.0
    patch = image[sl].astype(np.float32)
    image[sl] = np.clip(patch * keep * (1.0 - alpha) + np.asarray(colour, np.float32) * alpha + 0.5, 0,
                        255).astype(np.uint8)


def draw_expression(image: np.ndarray, box, message, K=None) -> np.ndarray:
    """``image`` (H, W, 3) uint8 BGR with ``message``'s recognised expression (a FaceExpression's
    ``label``, ``intensity``) written above the face's ``box`` (below its top edge when there is
    no room above), in the label's colour with a dark rim, and a bar as long as the intensity."""
    text = expression_text(getattr(message, "label", ""), getattr(message, "intensity", 0.0))
    if not text or box is None:
        return image
    out = image.copy()
    h, w = out.shape[:2]
    x0, y0, x1, _ = box
    scale = float(np.clip((x1 - x0) / 300.0, 0.4, 1.0))
    (tw, th), base = cv2.getTextSize(text, FONT, scale, 1)
    x = int(np.clip((x0 + x1 - tw) / 2, 2, max(2, w - tw - 2)))
    y = y0 - 10 if y0 - 10 - th - 6 > 0 else min(h - base - 8, y0 + th + 4)
    colour = EXPRESSION_BGR.get(message.label, TEXT_BGR)
    _rimmed_text(out, text, (x, y), scale, colour)
    if message.label != "neutral":
        bar = int(round(tw * float(np.clip(message.intensity, 0.0, 1.0))))
        cv2.rectangle(out, (x, y + base), (x + tw, y + base + 3), (0, 0, 0), -1)
        cv2.rectangle(out, (x, y + base), (x + bar, y + base + 3), colour, -1)
    return out


def draw_gaze_layer(image: np.ndarray, box, message, K=None) -> np.ndarray:
    """``image`` with a ``face/gaze`` message's rays drawn (:func:`.gaze_overlay.draw_gaze`) through
    the frame's intrinsics ``K`` (3, 3); unchanged without them."""
    if K is None or np.shape(K) != (3, 3):
        return image
    return draw_gaze(image, K, message.centres, message.directions, np.asarray(message.closed, bool))


#: Face layer -> draw(image, box, message, K) -> image; a layer without one draws nothing.
DRAWERS = {"expression": draw_expression, "gaze": draw_gaze_layer}
#: Face layer -> (the topic its messages come on, their message type's name); the renderer
#: subscribes to a layer asked for that has a drawer and whose type exists.
TOPICS = {"expression": ("face/expression", "FaceExpression"), "gaze": ("face/gaze", "FaceGaze")}
