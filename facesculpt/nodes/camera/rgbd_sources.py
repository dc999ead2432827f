"""RGB-D frame sources for the camera node: a folder of colour + 16-bit depth PNGs, and an Intel
RealSense through ``pyrealsense2`` (an RGB-D bag replays through :class:`.sources.BagImageSource`).
Each yields ``(RGBDFrame, stamp_ns)`` where a colour source yields ``(frame_bgr, stamp_ns)``; the
node turns an :class:`RGBDFrame` into an ``Image`` with its depth fields
(docs/guide/depth-cameras.md).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .sources import IMAGE_SUFFIXES, FrameSource, SourceError, resized_size

#: Names of a folder's calibration file (optional).
CALIBRATION_FILE = "camera.json"
_COLOR_DIRS = ("color", "rgb", "colour")
_COLOR_TAGS = ("_color", "_rgb", "_colour")


@dataclass
class RGBDFrame:
    """One RGB-D frame: color (H, W, 3) uint8 BGR; depth (DH, DW) uint16 mm (0: no measurement);
    depth_K (3, 3) float64 the depth image's intrinsics, px (None: the depth is aligned to the
    colour image and shares its K); depth_to_color (4, 4) float64 rigid transform, mm, from the
    depth camera's frame to the colour camera's (None: identity); K (3, 3) float64 the colour
    intrinsics the source knows, px (None: the node's ``K`` or ``fov_deg``)."""

    color: np.ndarray
    depth: np.ndarray
    depth_K: np.ndarray | None = None
    depth_to_color: np.ndarray | None = None
    K: np.ndarray | None = None


def resized_intrinsics(K: np.ndarray, size: tuple[int, int], width: int, height: int, mode: str) -> np.ndarray:
    """K (3, 3) of a ``size`` (W, H) frame after :func:`.sources.resize_frame` to ``width`` x
    ``height`` under ``mode``: scaled with the frame, and shifted by ``fill``'s centre crop."""
    w, h = size
    out_w, out_h = resized_size(w, h, width, height, mode)
    K = np.asarray(K, np.float64).copy()
    if (out_w, out_h) != (w, h):
        sx, sy = out_w / w, out_h / h
        K[0, 0] *= sx
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 1] *= sy
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    if mode == "fill" and width > 0 and height > 0:
        K[0, 2] -= (out_w - width) // 2
        K[1, 2] -= (out_h - height) // 2
    return K


def depth_fields(frame: RGBDFrame, color_K: np.ndarray) -> dict:
    """The ``Image`` depth fields of ``frame``: depth, depth_K (``color_K``, the colour image's K
    at the size it was read, when the depth is aligned to it), depth_to_color (or absent)."""
    depth_K = color_K if frame.depth_K is None else frame.depth_K
    fields = {"depth": np.ascontiguousarray(frame.depth, np.uint16),
              "depth_K": np.asarray(depth_K, np.float64).reshape(3, 3).copy()}
    if frame.depth_to_color is not None:
        fields["depth_to_color"] = np.asarray(frame.depth_to_color, np.float64).reshape(4, 4)
    return fields


# -- a folder of colour + depth PNGs ------------------------------------------------------------
def _pairs(folder: Path) -> list[tuple[Path, Path]]:
    """(colour, depth) files of ``folder``: ``color/`` (or ``rgb/``) and ``depth/`` subfolders
    paired by name (or by order when the names differ and the counts agree), or flat
    ``NAME_color.png`` (``_rgb``) beside ``NAME_depth.png``."""
    depth_dir = folder / "depth"
    color_dir = next((folder / d for d in _COLOR_DIRS if (folder / d).is_dir()), None)
    images = lambda d: sorted(p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)  # noqa: E731
    if color_dir is not None and depth_dir.is_dir():
        colors, depths = images(color_dir), images(depth_dir)
        by_stem = {p.stem: p for p in depths}
        if colors and all(p.stem in by_stem for p in colors):
            return [(p, by_stem[p.stem]) for p in colors]
        if colors and len(colors) == len(depths):
            return list(zip(colors, depths))
        raise SourceError(f"RGB-D folder {folder}: {len(colors)} colour and {len(depths)} depth images "
                          "that pair neither by name nor by count")
    pairs = []
    for p in images(folder):
        for tag in _COLOR_TAGS:
            if p.stem.endswith(tag):
                depth = p.with_name(p.stem[: -len(tag)] + "_depth.png")
                if depth.is_file():
                    pairs.append((p, depth))
    return pairs


def _matrix(calibration: dict, key: str, n: int, path: Path) -> np.ndarray | None:
    if key not in calibration:
        return None
    try:
        m = np.asarray(calibration[key], np.float64).reshape(n, n)
    except (TypeError, ValueError):
        raise SourceError(f"{path}: {key} must be {n * n} numbers (row-major)") from None
    if not np.all(np.isfinite(m)):
        raise SourceError(f"{path}: {key} must be finite numbers")
    return m


class RGBDFolderSource(FrameSource):
    """A folder of colour images and 16-bit depth PNGs (:func:`_pairs`), with an optional
    ``camera.json``: ``K`` and ``depth_K`` (9 numbers each, row-major, px), ``depth_to_color``
    (16 numbers, mm), ``depth_scale_mm`` (mm per depth unit, default 1; 0.2 for TUM's 5000 per
    metre) and ``fps`` (default 30). Without ``depth_K`` the depth is taken as aligned to the colour."""

    def __init__(self, path: str | Path, loop: bool = False, fps: float = 0.0):
        folder = Path(path)
        if not folder.is_dir():
            raise SourceError(f"RGB-D folder {folder} not found")
        self.pairs = _pairs(folder)
        if not self.pairs:
            raise SourceError(f"RGB-D folder {folder} holds no colour + depth pairs (color/ and depth/ "
                              "subfolders, or NAME_color.png beside NAME_depth.png)")
        cal_path = folder / CALIBRATION_FILE
        calibration = {}
        if cal_path.is_file():
            try:
                calibration = json.loads(cal_path.read_text())
            except (ValueError, UnicodeDecodeError):
                raise SourceError(f"{cal_path} is not valid JSON") from None
            if not isinstance(calibration, dict):
                raise SourceError(f"{cal_path} must hold a JSON object")
        self.K = _matrix(calibration, "K", 3, cal_path)
        self.depth_K = _matrix(calibration, "depth_K", 3, cal_path)
        self.depth_to_color = _matrix(calibration, "depth_to_color", 4, cal_path)
        self.scale_mm = float(calibration.get("depth_scale_mm", 1.0))
        if not 0 < self.scale_mm < 1000:
            raise SourceError(f"{cal_path}: depth_scale_mm must be in (0, 1000), got {self.scale_mm}")
        self.native_fps = fps if fps > 0 else float(calibration.get("fps", 30.0))
        self.loop = loop
        self.description = f"RGB-D folder {folder} ({len(self.pairs)} frames)"

    def read(self, i: int) -> RGBDFrame:
        """Frame ``i`` of the folder; SourceError naming the file that does not read."""
        color_path, depth_path = self.pairs[i]
        color = cv2.imread(str(color_path), cv2.IMREAD_COLOR)
        if color is None:
            raise SourceError(f"colour image {color_path} is not readable")
        depth = cv2.imread(str(depth_path), cv2.IMREAD_UNCHANGED)
        if depth is None or depth.dtype != np.uint16 or depth.ndim != 2:
            raise SourceError(f"depth image {depth_path} is not a single-channel 16-bit PNG")
        if self.scale_mm != 1.0:
            depth = np.clip(np.rint(depth * self.scale_mm), 0, 65535).astype(np.uint16)
        return RGBDFrame(color, depth, self.depth_K, self.depth_to_color, self.K)

    def frames(self):
        while True:
            for i in range(len(self.pairs)):
                yield self.read(i), time.time_ns()
            if not self.loop:
                return


def write_rgbd_folder(folder: str | Path, frames, K: np.ndarray | None = None, fps: float = 30.0,
                      depth_K: np.ndarray | None = None, depth_to_color: np.ndarray | None = None) -> Path:
    """Write ``frames`` (colour (H, W, 3) uint8, depth (DH, DW) uint16 mm) pairs as a folder
    :class:`RGBDFolderSource` reads: ``color/NNNNNN.png``, ``depth/NNNNNN.png`` and ``camera.json``."""
    folder = Path(folder)
    (folder / "color").mkdir(parents=True, exist_ok=True)
    (folder / "depth").mkdir(parents=True, exist_ok=True)
    for i, (color, depth) in enumerate(frames):
        cv2.imwrite(str(folder / "color" / f"{i:06d}.png"), color)
        cv2.imwrite(str(folder / "depth" / f"{i:06d}.png"), np.asarray(depth, np.uint16))
    calibration = {"fps": fps, "depth_scale_mm": 1.0}
    for key, m in (("K", K), ("depth_K", depth_K), ("depth_to_color", depth_to_color)):
        if m is not None:
            calibration[key] = np.asarray(m, np.float64).reshape(-1).tolist()
    (folder / CALIBRATION_FILE).write_text(json.dumps(calibration, indent=1))
    return folder


# -- Intel RealSense ----------------------------------------------------------------------------
class RealSenseSource(FrameSource):
    """An Intel RealSense camera (``serial``: which one; "" the first), colour and depth at
    ``width`` x ``height`` px and ``fps``, the depth aligned to the colour camera by librealsense
    and converted to mm."""

    def __init__(self, serial: str = "", width: int = 640, height: int = 480, fps: float = 30.0):
        try:
            import pyrealsense2 as rs
        except ImportError:
            raise SourceError("reading a RealSense camera needs the pyrealsense2 package "
                              "(pip install pyrealsense2), which is not installed") from None
        if len(rs.context().query_devices()) == 0:
            raise SourceError("no Intel RealSense camera is connected")
        config = rs.config()
        if serial:
            config.enable_device(serial)
        rate = int(round(fps)) if fps > 0 else 30
        config.enable_stream(rs.stream.color, width, height, rs.format.bgr8, rate)
        config.enable_stream(rs.stream.depth, width, height, rs.format.z16, rate)
        self.pipeline = rs.pipeline()
        try:
            profile = self.pipeline.start(config)
        except RuntimeError as exc:
            raise SourceError(f"the RealSense camera {serial or ''} does not start at {width}x{height} "
                              f"{rate} fps: {exc}") from None
        self.scale_mm = float(profile.get_device().first_depth_sensor().get_depth_scale()) * 1000.0
        self.align = rs.align(rs.stream.color)
        i = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        self.K = np.array([[i.fx, 0, i.ppx], [0, i.fy, i.ppy], [0, 0, 1.0]])
        self.native_fps = float(rate)
        self.description = f"RealSense {serial or 'camera'} {width}x{height}"

    def frames(self):
        while True:
            try:
                frames = self.align.process(self.pipeline.wait_for_frames())
            except RuntimeError as exc:
                raise SourceError(f"the RealSense camera stopped delivering frames: {exc}") from None
            color, depth = frames.get_color_frame(), frames.get_depth_frame()
            if not color or not depth:
                continue
            d = np.asanyarray(depth.get_data())
            d = d.copy() if abs(self.scale_mm - 1.0) < 1e-9 else np.clip(np.rint(d * self.scale_mm), 0, 65535)
            yield RGBDFrame(np.asanyarray(color.get_data()).copy(), d.astype(np.uint16), None, None, self.K), \
                time.time_ns()

    def close(self):
        try:
            self.pipeline.stop()
        except RuntimeError:
            pass
