"""The window's landmark correction mode (seed 002's interactive correction; docs/guide/
landmark-correction.md): the 68 iBUG landmarks of each fitted face are shown, the one under the cursor is
named, and a left-drag puts it where the button is let go.

:class:`CorrectionMode` is plain state, no window and no sockets: the renderer node feeds it the
face states it draws (:meth:`observe`: ``FaceState.landmarks``, the fit's iBUG-68 points, and
``FaceState.corrected``), the window's left-button events of correction mode (:meth:`handle`,
which returns the ``correct_landmark`` input events to publish: a few a second while dragging,
and one at the release), and draws the points over the shown frame (:meth:`draw`). The fitter
keeps the corrections (in the head's frame) and uses them in every later frame until
``clear_corrections``.
"""

from __future__ import annotations

import cv2
import numpy as np

from facesculpt.geometry.ibug68 import IBUG68_GROUPS

PICK_RADIUS_PX = 12.0      # a press this near a landmark grabs it (the nearest), px
SEND_PERIOD_S = 0.1        # while dragging, at most one correct_landmark per this, s
LANDMARK_BGR = (80, 220, 80)     # green dots: the fit's landmarks
CORRECTED_BGR = (255, 0, 255)    # magenta dots: landmarks a person corrected
ACTIVE_BGR = (255, 255, 255)     # white ring: the landmark under the cursor or being dragged
DOT_PX = 2

# Landmarks with a name of their own (1-based iBUG numbers); the others are named by their group.
_SPECIAL = {9: "chin", 28: "nose bridge top", 31: "nose tip", 34: "nose base centre",
            37: "right eye outer corner", 40: "right eye inner corner", 43: "left eye inner corner",
            46: "left eye outer corner", 49: "right mouth corner", 55: "left mouth corner",
            52: "upper lip centre", 58: "lower lip centre", 63: "inner upper lip centre",
            67: "inner lower lip centre"}


def landmark_name(number: int) -> str:
    """"NUMBER name" of iBUG landmark ``number`` (1..68; "left" is the subject's), e.g. "31 nose
    tip", "20 right eyebrow 3"."""
    if number in _SPECIAL:
        return f"{number} {_SPECIAL[number]}"
    for group, members in IBUG68_GROUPS.items():
        if number - 1 in members:
            return f"{number} {group.replace('_', ' ')} {number - members.start}"
    raise ValueError(f"iBUG landmarks are numbered 1..68, got {number}")


class CorrectionMode:
    """The landmarks the window shows for correction and the drag under way (see the module)."""

    def __init__(self, pick_radius_px: float = PICK_RADIUS_PX, send_period_s: float = SEND_PERIOD_S):
        self.pick_radius_px = float(pick_radius_px)
        self.send_period_s = float(send_period_s)
        self.landmarks: dict[int, np.ndarray] = {}  # face id -> (68, 2) float32 px (NaN: none)
        self.corrected: dict[int, set[int]] = {}    # face id -> iBUG numbers corrected
        self.drag: dict | None = None               # {"face", "number", "x", "y", "sent_at"}

    def observe(self, states) -> None:
        """The face states of the frame being shown (FaceState list, or None: no face)."""
        self.landmarks, self.corrected = {}, {}
        for state in states or []:
            points = getattr(state, "landmarks", None)
            if points is None or np.shape(points) != (68, 2):
                continue
            self.landmarks[int(state.face_id)] = np.asarray(points, np.float32)
            self.corrected[int(state.face_id)] = {int(k) for k in state.corrected or []}

    def nearest(self, x: float, y: float) -> tuple[int, int] | None:
        """(face id, iBUG number) of the landmark nearest pixel (x, y) within the pick radius."""
        best = None
        for face, points in self.landmarks.items():
            d = np.linalg.norm(points - [x, y], axis=1)
            d[~np.isfinite(d)] = np.inf
            k = int(np.argmin(d))
            if d[k] <= self.pick_radius_px and (best is None or d[k] < best[0]):
                best = (float(d[k]), face, k + 1)
        return None if best is None else best[1:]

    def handle(self, event: dict, now_s: float) -> list[dict]:
        """A left-button event of correction mode (``kind`` press / drag / release, x, y frame px);
        returns the InputEvent fields to publish (``correct_landmark`` commands)."""
        kind, x, y = event.get("kind"), float(event.get("x", np.nan)), float(event.get("y", np.nan))
        if kind == "press":
            hit = self.nearest(x, y)
            self.drag = None if hit is None else {"face": hit[0], "number": hit[1], "x": x, "y": y,
                                                  "sent_at": -np.inf}
            return []
        if self.drag is None or kind not in ("drag", "release"):
            return []
        drag = self.drag
        drag["x"], drag["y"] = x, y
        if kind == "release":
            self.drag = None
        elif now_s - drag["sent_at"] < self.send_period_s:
            return []
        drag["sent_at"] = now_s
        return [{"kind": "command", "command": "correct_landmark", "argument": str(drag["number"]),
                 "x": x, "y": y, "face": drag["face"]}]

    def draw(self, image: np.ndarray, pointer: tuple[float, float] | None = None) -> np.ndarray:
        """A copy of ``image`` (H, W, 3) uint8 BGR with the landmarks (green; corrected ones
        magenta), a white ring and the name of the one under ``pointer`` (frame px) or being
        dragged (drawn where the cursor holds it)."""
        out = image.copy()
        for face, points in self.landmarks.items():
            corrected = self.corrected.get(face, set())
            for k, (x, y) in enumerate(points, start=1):
                if not (np.isfinite(x) and np.isfinite(y)):
                    continue
                if self.drag is not None and (face, k) == (self.drag["face"], self.drag["number"]):
                    continue
                colour = CORRECTED_BGR if k in corrected else LANDMARK_BGR
                centre = (int(round(x)), int(round(y)))
                cv2.circle(out, centre, DOT_PX + 1, (0, 0, 0), -1, cv2.LINE_AA)
                cv2.circle(out, centre, DOT_PX, colour, -1, cv2.LINE_AA)
        active = None
        if self.drag is not None:
            active = (self.drag["number"], self.drag["x"], self.drag["y"], CORRECTED_BGR)
        elif pointer is not None:
            hit = self.nearest(*pointer)
            if hit is not None:
                x, y = self.landmarks[hit[0]][hit[1] - 1]
                active = (hit[1], x, y, CORRECTED_BGR if hit[1] in self.corrected.get(hit[0], ()) else LANDMARK_BGR)
        if active is not None:
            number, x, y, colour = active
            centre = (int(round(x)), int(round(y)))
            cv2.circle(out, centre, DOT_PX + 1, colour, -1, cv2.LINE_AA)
            cv2.circle(out, centre, DOT_PX + 5, ACTIVE_BGR, 1, cv2.LINE_AA)
            _label(out, landmark_name(number), (centre[0] + 10, centre[1] - 8))
        return out


def _label(image: np.ndarray, text: str, org: tuple[int, int]) -> None:
    """White text with a black rim at ``org`` (its baseline's left end), kept inside the frame."""
    scale = float(np.clip(min(image.shape[:2]) / 1000.0, 0.4, 0.8))
    (w, h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    x = int(np.clip(org[0], 2, max(2, image.shape[1] - w - 2)))
    y = int(np.clip(org[1], h + 2, image.shape[0] - 4))
    cv2.putText(image, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(image, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA)
