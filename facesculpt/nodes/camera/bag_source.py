"""Frames replayed from a bag's image topic (``bag:FILE``): colour, or colour + depth when the
recording has it (:class:`.rgbd_sources.RGBDFrame`)."""

from __future__ import annotations

import time

import numpy as np

from .rgbd_sources import RGBDFrame
from .sources import FrameSource, SourceError


class BagImageSource(FrameSource):
    """The `camera/image` records of a bag (or another topic), in order."""

    def __init__(self, path: str, topic: str = "camera/image", loop: bool = False, restamp: bool = True):
        from facesculpt.runtime.bag import BagReader

        self.reader = BagReader(path)
        self.topic = topic
        self.loop = loop
        self.restamp = restamp
        self.description = f"bag {path}"
        times = [r.time_ns for r in self.reader if r.topic == topic]
        if not times:
            raise SourceError(f"bag {path} has no {topic} messages")
        self.native_fps = (len(times) - 1) / max(1e-9, (times[-1] - times[0]) / 1e9) if len(times) > 1 else 30.0

    def frames(self):
        from facesculpt.msgs import Image, decode

        while True:
            for rec in self.reader:
                if rec.topic != self.topic:
                    continue
                _, msg = decode([rec.topic.encode()] + rec.frames, Image)
                stamp = time.time_ns() if self.restamp else msg.stamp
                if msg.depth is not None:  # an RGB-D recording: the depth and both cameras go along
                    yield RGBDFrame(np.array(msg.image), np.array(msg.depth), np.array(msg.depth_K),
                                    None if msg.depth_to_color is None else np.array(msg.depth_to_color),
                                    np.array(msg.K)), stamp
                    continue
                yield np.array(msg.image), stamp
            if not self.loop:
                return
