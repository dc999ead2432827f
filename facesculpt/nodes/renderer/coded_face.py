"""Rendering model-based coding's frames (`.fsc` files and the `coding/` topics): the keyframe's
fitted face moved as each frame's parameters say, composited from the keyframe.

Frame t's shape is neutral + mean + basis · c_t (model mm), posed by its similarity (a 7-vector:
:mod:`facesculpt.geometry.similarity`). The keyframe's fitted mesh is moved by the difference
between that and the keyframe's own posed shape, so the keyframe renders as itself, and the
keyframe image is composited onto it (:class:`Compositor`: uncovered background inpainted; the
background stays the keyframe's). The face's motion is carried over the head around it (hair,
forehead, ears: the compositor's ``head_motion``, as a pose edit does), so the still keyframe's hair
does not cut a seam across a moving head, and the chin's motion is blended into the neck and body below
the jaw (``body_motion``: :mod:`.body_motion`), so the keyframe's still shoulders do not tear from a
moving head. A mouth that opens wider than the keyframe's closed one gets the
painted interior of :mod:`.mouth_interior`, as reenactment does.
"""

from __future__ import annotations

import cv2
import numpy as np

from facesculpt.geometry.projection import project
from facesculpt.geometry.similarity import apply_similarity_vector

from .compositor import Compositor
from .frame_size_defaults import AUTO_MAX_FINE_EDGE_PX
from .mouth_interior import CLOSED_MOUTH_PX, INNER_LIP_FACEMESH, opening_px, paint_mouth_interior


def coded_compositor(width: int, height: int, ctx=None) -> Compositor:
    """The compositor a coded face is drawn with (``ctx``: a window's GL context, else its own):
    the bicubic kernel and a render mesh only as fine as the face's size needs. The whole head
    moves in every frame, so a decoder warps the head's region, not an edit's; the sinc and the
    finer mesh cost it much of its frame time for no change in the decoded face that the
    coding benchmark sees (docs/results/talking-heads.md)."""
    return Compositor(width, height, ctx=ctx, interpolation="cubic", max_fine_edge_px=AUTO_MAX_FINE_EDGE_PX)


class CodedFace:
    """Renders coded frames of one key.

    header: the stream header (width, height, K); keyframe: the keyframe image's bytes (WebP or
    JPEG); arrays: the key's arrays (key_vertices (V, 3) camera space, key_projected (V, 2) px, neutral (V, 3) mm, mean (3V,),
    basis (C, 3V)); triangles (T, 3) int; key_pose (7,) and key_coeffs (C,): the keyframe's own
    record; lips: inner-lip vertex ids (default: the face mesh's for V = 468, else no painted
    mouth); compositor: one to draw with (e.g. :func:`coded_compositor` on a window's GL context),
    else a new :func:`coded_compositor`;
    head_motion: carry the face's motion over the hair and neck around it (else only the face moves);
    body_motion: with head_motion, the chin's motion over the neck and body below the jaw too."""

    def __init__(self, header: dict, keyframe: bytes, arrays: dict, triangles: np.ndarray,
                 key_pose: np.ndarray, key_coeffs: np.ndarray, lips=None, compositor: Compositor | None = None,
                 head_motion: bool = True, body_motion: bool = True):
        self.image = cv2.imdecode(np.frombuffer(keyframe, np.uint8), cv2.IMREAD_COLOR)
        if self.image is None:
            raise ValueError("the coded stream's keyframe is not an image")
        self.width, self.height = int(header["width"]), int(header["height"])
        if self.image.shape[:2] != (self.height, self.width):
            raise ValueError(f"the keyframe is {self.image.shape[1]}x{self.image.shape[0]}, its header says "
                             f"{self.width}x{self.height}")
        self.arrays = arrays
        self.triangles = np.asarray(triangles, np.int32)
        self.K = None if header.get("K") is None else np.asarray(header["K"], np.float64)
        V = len(arrays["key_vertices"])
        self.lips = (np.asarray(INNER_LIP_FACEMESH) if V == 468 else None) if lips is None else np.asarray(lips)
        self.key_opening = opening_px(arrays["key_projected"][self.lips]) if self.lips is not None else np.inf
        self.compositor = compositor if compositor is not None else coded_compositor(self.width, self.height)
        self._own_compositor = compositor is None
        self.head_motion = ("body" if body_motion else True) if head_motion else False
        self.anchor = self.posed(key_pose, key_coeffs)
        self.last = (np.asarray(key_pose, np.float64), np.asarray(key_coeffs, np.float64))

    def shape(self, coeffs: np.ndarray) -> np.ndarray:
        """(V, 3) float64 model mm: the decoded shape of ``coeffs`` (C,)."""
        a = self.arrays
        return (a["neutral"] + (a["mean"] + np.asarray(coeffs, np.float64) @ a["basis"]).reshape(-1, 3)).astype(np.float64)

    def posed(self, pose: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
        """(V, 3) float64 camera space: the decoded shape under ``pose`` (7,)."""
        return apply_similarity_vector(pose, self.shape(coeffs))

    def render(self, present: bool, pose: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 BGR: a frame with these parameters (``present`` False: the last frame
        with a face is held)."""
        if present:
            self.last = (np.asarray(pose, np.float64), np.asarray(coeffs, np.float64))
        a = self.arrays
        deformed = (a["key_vertices"] + self.posed(*self.last) - self.anchor).astype(np.float32)
        out = self.compositor.render(self.image, a["key_vertices"], a["key_projected"], self.triangles, deformed,
                                     head_motion=self.head_motion)
        if self.key_opening < CLOSED_MOUTH_PX:
            lips = deformed[self.lips].astype(np.float64)
            out = paint_mouth_interior(out, project(lips, self.K) if self.K is not None else lips[:, :2],
                                       self.key_opening)
        return out

    def release(self) -> None:
        """Frees the compositor's GL resources if this object made it."""
        if self._own_compositor:
            self.compositor.release()
