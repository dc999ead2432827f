"""Frame sources for the camera node: webcam, video file, still image (with a
virtual camera moving over it), and bags. Each yields ``(frame_bgr, stamp_ns)``;
none of them knows about sockets."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp"}


class SourceError(RuntimeError):
    """A source that cannot be opened or read; the message names it."""


RESIZE_MODES = ("fit", "fill", "stretch")


def resized_size(w: int, h: int, width: int, height: int, mode: str = "fit") -> tuple[int, int]:
    """The (width, height) px a w x h frame is resized to for a requested ``width`` x ``height``.

    A zero keeps the aspect ratio from the other side; both zero keep the frame's size. With both
    given, ``mode`` says what happens to an aspect ratio that differs: ``fit`` scales to the
    largest size inside the box (aspect kept, one side may come out shorter), ``fill`` scales to
    cover the box and :func:`resize_frame` crops the centre (aspect kept, exactly the box),
    ``stretch`` distorts to the box.
    """
    if mode not in RESIZE_MODES:
        raise ValueError(f"resize mode {mode!r} is not one of {', '.join(RESIZE_MODES)}")
    if width <= 0 and height <= 0:
        return w, h
    if width <= 0:
        return max(1, round(w * height / h)), height
    if height <= 0:
        return width, max(1, round(h * width / w))
    if mode == "stretch":
        return width, height
    scale = (min if mode == "fit" else max)(width / w, height / h)
    return max(1, round(w * scale)), max(1, round(h * scale))


def resize_frame(frame: np.ndarray, width: int, height: int, mode: str = "fit") -> np.ndarray:
    """The frame (H, W, 3) resized for a requested ``width`` x ``height`` px under ``mode``
    (:func:`resized_size`); ``fill`` crops the centre of the scaled frame to exactly the box."""
    h, w = frame.shape[:2]
    out_w, out_h = resized_size(w, h, width, height, mode)
    if (out_w, out_h) != (w, h):
        frame = _scaled(frame, out_w, out_h)
    if mode == "fill" and width > 0 and height > 0 and (out_w, out_h) != (width, height):
        x0, y0 = (out_w - width) // 2, (out_h - height) // 2
        frame = frame[y0:y0 + height, x0:x0 + width]
    return frame


def _scaled(frame: np.ndarray, width: int, height: int) -> np.ndarray:
    w = frame.shape[1]
    # INTER_AREA costs several times INTER_LINEAR: it only pays for itself on strong reductions.
    interp = cv2.INTER_AREA if width * 2 <= w else cv2.INTER_LINEAR
    return cv2.resize(frame, (width, height), interpolation=interp)


def virtual_camera_view(image: np.ndarray, t: float, *, max_rotation_deg: float = 6.0,
                        zoom: float = 0.08, pan: float = 0.04) -> np.ndarray:
    """The still ``image`` seen by a slowly moving virtual camera at time ``t`` (seconds):
    a smooth in-plane rotation, zoom and pan (same size out, border replicated)."""
    h, w = image.shape[:2]
    angle = max_rotation_deg * math.sin(2 * math.pi * t / 7.0)
    scale = 1.0 + zoom * math.sin(2 * math.pi * t / 11.0)
    M = cv2.getRotationMatrix2D((w / 2, h / 2), angle, scale)
    M[0, 2] += pan * w * math.sin(2 * math.pi * t / 5.0)
    M[1, 2] += pan * h * math.sin(2 * math.pi * t / 9.0 + 1.0)
    return cv2.warpAffine(image, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


class FrameSource:
    """Base: iterate frames; ``native_fps`` is the source's own rate (0 when unknown); ``live``:
    frames come at the source's pace whether read or not (a webcam), else each is made when read."""

    native_fps = 0.0
    description = ""
    live = False

    def frames(self) -> Iterator[tuple[np.ndarray, int]]:
        raise NotImplementedError

    def close(self) -> None:
        pass


class VideoSource(FrameSource):
    """A video file or a webcam index, read with OpenCV."""

    def __init__(self, spec: str | int, loop: bool = False):
        self.spec = spec
        self.loop = loop
        self.is_webcam = isinstance(spec, int)
        self.live = self.is_webcam
        if not self.is_webcam and not Path(spec).is_file():
            raise SourceError(f"video file {spec} not found")
        self.cap = self._open()
        fps = self.cap.get(cv2.CAP_PROP_FPS)
        self.native_fps = fps if fps and math.isfinite(fps) and 0 < fps < 1000 else 30.0
        self.frame_count = int(self.cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0) if not self.is_webcam else 0
        self.description = f"webcam {spec}" if self.is_webcam else f"video {spec}"
        self.problems: list[str] = []   # what went wrong while reading; the node reports it

    def _open(self) -> cv2.VideoCapture:
        cap = cv2.VideoCapture(self.spec)
        if not cap.isOpened():
            kind = "webcam" if self.is_webcam else "video file"
            raise SourceError(f"cannot open {kind} {self.spec}")
        return cap

    def frames(self):
        read = 0
        while True:
            ok, frame = self.cap.read()
            stamp = time.time_ns()
            if ok and frame is not None and frame.ndim == 3:
                read += 1
                yield frame, stamp
                continue
            if self.is_webcam:
                raise SourceError(f"webcam {self.spec} stopped delivering frames (unplugged?)")
            # The container announced more frames than decoded: the file is corrupt or cut short.
            # A few frames of slack: the announced count is an estimate for some containers.
            if self.frame_count and read < self.frame_count - 2:
                self.problems.append(f"video {self.spec}: decoding stopped at frame {read} of "
                                     f"{self.frame_count} (corrupt or truncated file)")
            read = 0
            if not self.loop:
                return
            self.cap.release()
            self.cap = self._open()

    def close(self):
        self.cap.release()


class ImageSource(FrameSource):
    """A still image, optionally seen by a moving virtual camera (``motion``)."""

    def __init__(self, path: str, motion: bool = False, fps: float = 30.0):
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise SourceError(f"image {path} not found or not readable")
        self.image = img
        self.motion = motion
        self.native_fps = fps
        self.description = f"image {path}" + (" (virtual camera)" if motion else "")

    def frames(self):
        i = 0
        while True:
            t = i / self.native_fps
            yield (virtual_camera_view(self.image, t) if self.motion else self.image.copy()), time.time_ns()
            i += 1


# The head-and-shoulders part of astronaut.png (x0, y0, x1, y1), shown at 640x480.
EMBEDDED_CROP = (100, 0, 420, 240)


def embedded_source(fps: float = 30.0) -> ImageSource:
    """The main job's default input: a real face photo shipped with the install
    (scikit-image's astronaut.png), framed on the head, seen by a moving virtual camera."""
    from facesculpt.paths import embedded_face_image

    source = ImageSource(str(embedded_face_image()), motion=True, fps=fps)
    x0, y0, x1, y1 = EMBEDDED_CROP
    source.image = cv2.resize(source.image[y0:y1, x0:x1], (640, 480), interpolation=cv2.INTER_CUBIC)
    source.description = "embedded face photo (astronaut.png, virtual camera)"
    return source
