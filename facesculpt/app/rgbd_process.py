"""`facesculpt process` of an RGB-D recording (issue 49): the input's depth reaches the fit, and
the edited depth is written on request.

    facesculpt process rgbd_folder/ -o out.mp4 --edits nose_longer --model sfm
    facesculpt process bag:rgbd.mcap -o out.mp4 --edits chin --depth-out out_depth/%05d.png
    facesculpt process rgbd.mcap -o out.mp4 --edits chin --depth-out edited.mcap

An RGB-D recording is a folder of colour + 16-bit depth PNGs
(:class:`~facesculpt.nodes.camera.rgbd_sources.RGBDFolderSource`) or a bag (``bag:FILE`` or a
``.mcap`` file) whose ``camera/image`` messages carry depth. Each frame's fit is refined on its
depth (:mod:`facesculpt.nodes.fitter.depth_fitting`), with the recording's own colour intrinsics
(a folder without them in ``camera.json``: ``--fov``). ``--depth-out`` writes the edited depth
(:mod:`facesculpt.nodes.renderer.edited_depth`) as numbered 16-bit PNGs (a printf pattern: no
file it would make may exist yet) or as an RGB-D bag (``.mcap``: the edited colour frames with
the edited depth, replayable with ``bag:``; written under a temporary name and renamed when
complete, as the video is).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from facesculpt.nodes.camera.sources import SourceError

#: Suffixes of the image files an edited depth pattern may write (16-bit, lossless).
DEPTH_SUFFIXES = (".png", ".tif", ".tiff")


def input_file(spec: str) -> str:
    """The file or folder an input spec names (``bag:FILE`` -> FILE)."""
    return spec[4:] if spec.startswith("bag:") else spec


def is_rgbd_input(spec: str) -> bool:
    """``spec`` names an RGB-D recording: a folder holding colour + depth pairs, ``bag:FILE``, or a
    ``.mcap`` file (whether its frames carry depth is checked when it is opened)."""
    path = Path(input_file(spec))
    if spec.startswith("bag:") or (path.suffix.lower() == ".mcap" and path.is_file()):
        return True
    if not path.is_dir():
        return False
    from facesculpt.nodes.camera.rgbd_sources import _pairs

    try:
        return bool(_pairs(path))
    except (SourceError, OSError):
        return False


class RGBDInput:
    """An RGB-D recording as ``process`` reads it: ``frames()`` yields ((colour (H, W, 3) uint8,
    :class:`DepthImage`), stamp); ``K`` (3, 3) the colour intrinsics at the recorded size, px (the
    recording's, else a pinhole of ``fov_deg``); ``native_fps``, ``frame_count``, ``size`` (W, H).
    One sentence (ValueError) when the recording cannot be read or holds no depth."""

    def __init__(self, spec: str, fov_deg: float = 60.0):
        from facesculpt.nodes.camera.bag_source import BagImageSource
        from facesculpt.nodes.camera.intrinsics import intrinsics_from_fov
        from facesculpt.nodes.camera.rgbd_sources import RGBDFolderSource

        path = input_file(spec)
        if not Path(path).exists():
            raise FileNotFoundError(f"cannot read {path}: no such file or folder")
        try:
            if Path(path).is_dir():
                self.source = RGBDFolderSource(path)
                self.frame_count = len(self.source.pairs)
            else:
                self.source = BagImageSource(path, restamp=False)
                self.frame_count = sum(r.topic == "camera/image" for r in self.source.reader)
            first = next(iter(self.source.frames()))[0]
        except (SourceError, ValueError, OSError) as exc:
            raise ValueError(f"cannot read {path} as an RGB-D recording: {exc}") from None
        if isinstance(first, np.ndarray):
            raise ValueError(f"cannot read {path} as an RGB-D recording: its camera/image frames carry no depth")
        h, w = first.color.shape[:2]
        self.size = (w, h)
        self.K = first.K if first.K is not None else intrinsics_from_fov(w, h, fov_deg)
        self.native_fps = self.source.native_fps
        self.description = self.source.description

    def frames(self):
        from facesculpt.nodes.fitter.depth_fitting import DepthImage

        for frame, stamp in self.source.frames():
            if isinstance(frame, np.ndarray):
                raise ValueError(f"{self.description}: a camera/image frame without depth among RGB-D frames")
            depth_K = self.K if frame.depth_K is None else frame.depth_K
            yield (frame.color, DepthImage(frame.depth, np.asarray(depth_K, np.float64), frame.depth_to_color)), stamp

    def close(self) -> None:
        self.source.close()


def colour_intrinsics(source: RGBDInput, width: int) -> np.ndarray:
    """The colour K (3, 3) px of ``source``'s frames after ``process``'s resize to ``width`` (0: none)."""
    from facesculpt.nodes.camera.rgbd_sources import resized_intrinsics

    return resized_intrinsics(source.K, source.size, width, 0, "fit")


class DepthBag:
    """An RGB-D bag being written (``path``): each :meth:`write` adds one ``camera/image`` message
    (the edited colour frame, its K, the edited depth with its K and transform), stamped
    ``frames / fps``; the depth stored as a lossless 16-bit PNG."""

    def __init__(self, path: str | Path, fps: float):
        from facesculpt.runtime.bag import BagWriter

        self.path, self.fps, self.frames = Path(path), float(fps) or 30.0, 0
        self.writer = BagWriter(self.path, compression="png")

    def write(self, item: tuple) -> None:
        from facesculpt.msgs import Image

        colour, K, depth = item
        stamp = int(round(self.frames / self.fps * 1e9))
        msg = Image(stamp=stamp, seq=self.frames, image=np.ascontiguousarray(colour), K=np.asarray(K, np.float64),
                    frame_size=[colour.shape[1], colour.shape[0]], depth=depth.depth,
                    depth_K=np.asarray(depth.K, np.float64), depth_to_color=depth.depth_to_color)
        self.writer.write(stamp, "camera/image", msg.to_frames())
        self.frames += 1

    def close(self) -> None:
        self.writer.close()


class DepthImages:
    """Edited depth images written as a numbered sequence (``pattern % index``, index from 0),
    16-bit; refuses a pattern whose names exist already (a user's files are never overwritten)."""

    def __init__(self, pattern: str):
        from facesculpt.app.image_sequence import ImageSequenceOutput

        self.images = ImageSequenceOutput(pattern)  # checks the pattern's field
        if Path(pattern % 0).suffix.lower() not in DEPTH_SUFFIXES:
            raise ValueError(f"--depth-out {pattern}: 16-bit depth images are written as {', '.join(DEPTH_SUFFIXES)}")
        if Path(pattern % 0).exists():
            raise ValueError(f"--depth-out {pattern}: {pattern % 0} exists already; the edited depth is never "
                             f"written over existing files (choose another pattern or folder)")
        self.path = pattern

    @property
    def frames(self) -> int:
        return self.images.frames

    def write(self, item: tuple) -> None:
        self.images.write(item[2].depth)

    def close(self) -> None:
        pass


def open_depth_output(spec: str, input_spec: str, fps: float):
    """The edited depth's writer for ``--depth-out`` ``spec``: :class:`DepthImages` for a printf
    pattern, a staged :class:`DepthBag` for a ``.mcap`` file (:class:`.safe_output.StagedVideo`);
    ValueError in one sentence for anything else or a target over the input."""
    from facesculpt.app.safe_output import StagedVideo, refuse_output_over_input

    refuse_output_over_input(input_file(input_spec), spec)
    if "%" in spec:
        return DepthImages(spec)
    if Path(spec).suffix.lower() != ".mcap":
        raise ValueError(f"--depth-out {spec}: the edited depth is written as 16-bit PNGs (a pattern such as "
                         f"depth/%05d.png) or as an RGB-D bag (.mcap)")
    if not Path(spec).expanduser().resolve().parent.is_dir():
        raise ValueError(f"--depth-out {spec}: its folder does not exist")
    return StagedVideo(spec, lambda path: DepthBag(path, fps))


def write_edited_depth(output, frame_image: np.ndarray, K: np.ndarray, depth, result, triangles) -> None:
    """Write one frame's edited depth to ``output`` (:func:`open_depth_output`): ``depth`` (a
    :class:`DepthImage`) with every face of ``result`` (a :class:`FrameResult`) drawn as edited in
    place of its fit; ``frame_image`` the edited colour frame and ``K`` its intrinsics."""
    from facesculpt.nodes.renderer.edited_depth import edited_depth

    d = depth.depth
    for key, deformed in result.deformed.items():
        d = edited_depth(d, depth.K, result.fits[key].vertices, deformed, triangles, depth.depth_to_color)
    output.write((frame_image, K, type(depth)(d, depth.K, depth.depth_to_color)))
