"""Which frame source a camera spec names (:func:`open_source`): the colour sources of
:mod:`.sources` and the RGB-D ones of :mod:`.rgbd_sources`, apart from both so that neither
imports the other's sources."""

from __future__ import annotations

from pathlib import Path

from .bag_source import BagImageSource
from .rgbd_sources import RealSenseSource, RGBDFolderSource
from .sources import IMAGE_SUFFIXES, FrameSource, ImageSource, VideoSource, embedded_source


def open_source(spec: str, *, loop: bool = False, motion: bool = False, fps: float = 30.0) -> FrameSource:
    """``"0"`` (webcam index), a video file, an image file, ``bag:FILE``, ``embedded``
    (a face photo shipped with the install, seen by a moving virtual camera), or an RGB-D source
    (:mod:`.rgbd_sources`): a folder of colour + depth PNGs, or ``realsense[:SERIAL]``."""
    spec = str(spec).strip()
    if spec == "realsense" or spec.startswith("realsense:") or Path(spec).is_dir():
        if Path(spec).is_dir():
            return RGBDFolderSource(spec, loop=loop)   # its rate from its camera.json
        return RealSenseSource(spec.partition(":")[2], fps=fps if fps > 0 else 30.0)
    if spec == "embedded":
        return embedded_source(fps if fps > 0 else 30.0)
    if spec.startswith("bag:"):
        return BagImageSource(spec[4:], loop=loop)
    if spec.lstrip("-").isdigit():
        return VideoSource(int(spec))
    path = Path(spec)
    if path.suffix.lower() in IMAGE_SUFFIXES:
        return ImageSource(spec, motion=motion, fps=fps if fps > 0 else 30.0)
    return VideoSource(spec, loop=loop)
