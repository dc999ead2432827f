"""The camera node: frames from a webcam, a video file, a still image or a bag
on `camera/image`, stamped with their capture time, with intrinsics K."""

from __future__ import annotations

import time

import numpy as np

from facesculpt.msgs import Image
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import ConfigurationError, Param

from .intrinsics import intrinsics_from_fov
from .sources import RESIZE_MODES, SourceError, open_source, resize_frame


class CameraNode(Node):
    """Publishes camera/image from a webcam, video, image or bag."""

    NAME = "camera"
    PARAMS = {
        "source": Param("0", "webcam index, video file, image file, bag:FILE, or embedded"),
        "width": Param(0, "resize to this width, px (0: keep; aspect kept if height is 0)", range=(0, 16384)),
        "height": Param(0, "resize to this height, px (0: keep; aspect kept if width is 0)", range=(0, 16384)),
        "resize": Param("fit", "with width and height both set: fit (largest size inside, aspect kept), "
                               "fill (cover and crop the centre, aspect kept) or stretch", choices=RESIZE_MODES),
        "fps": Param(0.0, "pacing, frames/s; 0: the source's own rate; -1: as fast as possible", range=(-1.0, 1000.0)),
        "loop": Param(False, "restart a video or bag at its end"),
        "motion": Param(False, "still image: move a virtual camera over it"),
        "fov_deg": Param(60.0, "horizontal field of view for K, degrees, unless K is given", range=(1.0, 179.0)),
        "K": Param([], "9 numbers, row-major, for the output size (empty: from fov_deg)"),
        "max_frames": Param(0, "stop after this many frames (0: no limit)", range=(0, None)),
        "wait_subscribers": Param(0, "hold the first frame until this many subscribers listen (recording)",
                                  range=(0, 1000)),
        "wait_timeout_s": Param(10.0, "longest hold for wait_subscribers, s", range=(0.0, 3600.0)),
    }

    def setup(self):
        p = self.params
        self.pub = self.advertise("camera/image", Image)
        try:
            self.source = open_source(p.source, loop=p.loop, motion=p.motion, fps=p.fps if p.fps > 0 else 30.0)
        except (SourceError, FileNotFoundError) as exc:  # no such camera or file: a respawn cannot help
            raise ConfigurationError(f"camera: {exc}") from None
        self.frames = self.source.frames()
        rate = p.fps if p.fps > 0 else (self.source.native_fps if p.fps == 0 else 0.0)
        self.period = 1.0 / rate if rate > 0 else 0.0
        self.sent = 0
        self.K_fixed = None
        if p.K:
            if len(p.K) != 9:
                raise ValueError(f"camera.K needs 9 numbers, got {len(p.K)}")
            self.K_fixed = np.asarray(p.K, dtype=np.float64).reshape(3, 3)
        self._K_cache: dict[tuple, np.ndarray] = {}
        self.wait_until = time.monotonic() + p.wait_timeout_s if p.wait_subscribers else 0.0
        self.log.info("%s at %s", self.source.description, f"{rate:.1f} fps" if rate else "full speed")
        self.timer(self.period, self.on_tick)

    def intrinsics(self, width: int, height: int) -> np.ndarray:
        if self.K_fixed is not None:
            return self.K_fixed
        key = (width, height)
        if key not in self._K_cache:
            self._K_cache[key] = intrinsics_from_fov(width, height, self.params.fov_deg)
        return self._K_cache[key]

    def on_tick(self):
        if self.wait_until:
            if self.pub.subscriber_count() < self.params.wait_subscribers and time.monotonic() < self.wait_until:
                return
            self.wait_until = 0.0
        try:
            frame, stamp = next(self.frames)
            self._report_problems()
        except StopIteration:
            self._report_problems()
            self.log.info("end of %s after %d frames", self.source.description, self.sent)
            self.shutdown()
            return
        except SourceError as exc:
            self.count("source_errors")
            self.log.error("%s", exc)
            self.shutdown()
            return
        frame = resize_frame(frame, self.params.width, self.params.height, self.params.resize)
        h, w = frame.shape[:2]
        self.sent += 1
        self.pub.publish(Image(stamp=stamp, seq=self.sent, frame_id="camera",
                               image=np.ascontiguousarray(frame), K=self.intrinsics(w, h)))
        if self.params.max_frames and self.sent >= self.params.max_frames:
            self.shutdown()

    def _report_problems(self) -> None:
        problems = getattr(self.source, "problems", None)
        while problems:
            self.count("source_errors")
            self.log.warning("%s", problems.pop(0))

    def teardown(self):
        if hasattr(self, "source"):
            self.source.close()
