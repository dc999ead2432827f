"""Writing the rendered frames to a video file with PyAV (FFmpeg), optionally with the sound of
the input video copied in sync."""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path

import numpy as np

# The encoder a suffix gets unless told otherwise: H.264 where the container takes it; Motion
# JPEG in .avi (what players expect there).
CODEC_BY_SUFFIX = {".mp4": "libx264", ".m4v": "libx264", ".mov": "libx264", ".mkv": "libx264", ".avi": "mjpeg"}
# Encoders that take a constant-rate-factor quality (lower: better, larger; 18 is visually lossless).
CRF_CODECS = ("libx264", "libx265")
DEFAULT_CRF = 18
# Their speed presets, slowest to fastest (x264's and x265's names); the encoder's own default is medium.
PRESETS = ("placebo", "veryslow", "slower", "slow", "medium", "fast", "faster", "veryfast", "superfast",
           "ultrafast")
# ``preset="auto"``: the encoder's default up to this many pixels a frame (1920x1080), above it
# AUTO_LARGE_PRESET: at 4K the default preset alone takes more than two cores' time for 15 fps.
AUTO_MAX_DEFAULT_PIXELS = 1920 * 1080
AUTO_LARGE_PRESET = "ultrafast"


def available_codecs() -> list[str]:
    """Video encoders this FFmpeg build has among the usual ones (names for ``codec``)."""
    import av

    names = ("libx264", "libx265", "mpeg4", "mjpeg", "ffv1", "libvpx-vp9", "libaom-av1", "prores_ks")
    out = []
    for name in names:
        try:
            av.codec.Codec(name, "w")
        except Exception:  # not in this build
            continue
        out.append(name)
    return out


class VideoOutput:
    """Appends (H, W, 3) uint8 BGR frames to ``path`` at ``fps`` frames per second.

    The file is opened at the first frame (its size fixes the video's; an odd side is padded by
    one replicated row or column, as 4:2:0 needs even sides). ``codec``: an FFmpeg encoder name
    (default by suffix, :data:`CODEC_BY_SUFFIX`), ``crf``: its quality where it has one,
    ``preset``: its speed preset where it has one (:data:`PRESETS`; None: the encoder's default;
    "auto": the default up to :data:`AUTO_MAX_DEFAULT_PIXELS` a frame, :data:`AUTO_LARGE_PRESET`
    above). Frames above :data:`AUTO_MAX_DEFAULT_PIXELS` are converted to 4:2:0 by OpenCV, smaller
    ones by FFmpeg's swscale (both BT.601, limited range).
    ``audio_from``: a media file whose first audio track is copied into the output, in sync with
    the frames and cut to their duration. Raises ValueError for an unknown suffix, codec or a
    frame of another size, RuntimeError when the file cannot be opened for writing.

    Before each frame the free space is checked: below ``reserve_bytes`` (default: one raw frame,
    at least 1 MiB) the file is finalised -- what was written stays playable -- and
    OSError(ENOSPC) is raised once; later frames are dropped (``dropped``).
    """

    def __init__(self, path: str | Path, fps: float = 30.0, reserve_bytes: int | None = None, *,
                 codec: str | None = None, crf: int = DEFAULT_CRF, preset: str | None = None,
                 audio_from: str | Path | None = None):
        self.path = Path(path).expanduser()
        suffix = self.path.suffix.lower()
        if suffix not in CODEC_BY_SUFFIX:
            raise ValueError(f"video output {self.path}: unknown suffix {suffix!r} "
                             f"(known: {', '.join(sorted(CODEC_BY_SUFFIX))})")
        if not fps > 0:
            raise ValueError(f"video output fps must be > 0, got {fps}")
        self.codec = codec or CODEC_BY_SUFFIX[suffix]
        if self.codec not in available_codecs():
            raise ValueError(f"video codec {self.codec!r} is not available here "
                             f"(choose one of {', '.join(available_codecs())})")
        if not 0 <= crf <= 51:
            raise ValueError(f"crf must be in [0, 51], got {crf}")
        if preset is not None and preset not in (*PRESETS, "auto"):
            raise ValueError(f"unknown encoder preset {preset!r} (auto or one of {', '.join(PRESETS)})")
        self.fps = float(fps)
        self.crf = int(crf)
        self.preset = preset
        self.audio_from = Path(audio_from) if audio_from else None
        self.size: tuple[int, int] | None = None
        self.frames = 0
        self.dropped = 0
        self.failed = ""
        self.reserve_bytes = reserve_bytes
        self._container = None
        self._stream = None
        self._audio = None  # _AudioCopy while a sound track is copied

    def _open(self, w: int, h: int) -> None:
        import av

        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._container = av.open(str(self.path), "w")
        except (OSError, av.error.FFmpegError) as exc:
            raise RuntimeError(f"cannot open {self.path} for writing: {getattr(exc, 'strerror', exc)}") from None
        self._rate = Fraction(self.fps).limit_denominator(1001)
        stream = self._container.add_stream(self.codec, rate=self._rate)
        stream.width, stream.height = w + w % 2, h + h % 2
        stream.pix_fmt = "yuvj420p" if self.codec == "mjpeg" else "yuv420p"
        if self.codec in CRF_CODECS:
            stream.options = {"crf": str(self.crf)}
            preset = self.preset
            if preset == "auto":
                preset = AUTO_LARGE_PRESET if w * h > AUTO_MAX_DEFAULT_PIXELS else None
            if preset is not None:
                stream.options["preset"] = preset
        self._stream = stream
        self._audio = _AudioCopy.open(self.audio_from, self._container) if self.audio_from else None
        self.size = (w, h)

    def write(self, frame_bgr: np.ndarray) -> None:
        if not (isinstance(frame_bgr, np.ndarray) and frame_bgr.dtype == np.uint8 and frame_bgr.ndim == 3
                and frame_bgr.shape[2] == 3):
            raise ValueError("video output takes (H, W, 3) uint8 BGR frames")
        h, w = frame_bgr.shape[:2]
        if self.failed:
            self.dropped += 1
            return
        if self._container is None:
            self._open(w, h)
        elif (w, h) != self.size:
            raise ValueError(f"video output {self.path} is {self.size[0]}x{self.size[1]}; got a {w}x{h} frame")
        reserve = self.reserve_bytes if self.reserve_bytes is not None else max(1 << 20, frame_bgr.nbytes)
        free = _free_bytes(self.path.parent)
        if free is not None and free < reserve:
            self.close()  # finalise while there is still room for the index
            self.failed = (f"video output {self.path}: disk full ({free} bytes free) after {self.frames} frames; "
                           f"those frames are saved, later ones are dropped")
            self.dropped += 1
            raise OSError(28, self.failed)
        self._encode(frame_bgr)

    def _encode(self, frame_bgr: np.ndarray) -> None:
        import av

        if frame_bgr.shape[1] % 2 or frame_bgr.shape[0] % 2:
            frame_bgr = np.pad(frame_bgr, ((0, frame_bgr.shape[0] % 2), (0, frame_bgr.shape[1] % 2), (0, 0)),
                               mode="edge")
        h, w = frame_bgr.shape[:2]
        if w * h > AUTO_MAX_DEFAULT_PIXELS and self._stream.pix_fmt == "yuv420p":
            # OpenCV's BGR -> I420 (the same BT.601 limited-range matrix as swscale's, luma within 1)
            # takes a few ms on a 4K frame where PyAV's bgr24 frame and swscale take about 20
            import cv2

            yuv = cv2.cvtColor(np.ascontiguousarray(frame_bgr), cv2.COLOR_BGR2YUV_I420)
            frame = av.VideoFrame.from_ndarray(yuv, format="yuv420p")
        else:
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame_bgr), format="bgr24")
        frame.pts = self.frames
        frame.time_base = 1 / self._rate
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self.frames += 1
        if self._audio is not None:
            self._audio.mux_until(self.frames / self.fps)

    def close(self) -> None:
        if self._container is None:
            return
        try:
            for packet in self._stream.encode(None):  # flush the encoder's delayed frames
                self._container.mux(packet)
            if self._audio is not None:
                self._audio.mux_until(self.frames / self.fps)
                self._audio.close()
        finally:
            self._container.close()
            self._container = None

    def __enter__(self) -> VideoOutput:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _AudioCopy:
    """The first audio track of a media file, copied packet by packet (no re-encoding) into an
    output container as the video grows; ``mux_until(t)`` copies what starts before t seconds."""

    def __init__(self, source, in_stream, out_stream, container):
        self.source, self.in_stream, self.out_stream, self.container = source, in_stream, out_stream, container
        self.packets = source.demux(in_stream)
        self.pending = None
        self.start = in_stream.start_time or 0

    @classmethod
    def open(cls, path: Path, container) -> _AudioCopy | None:
        import av

        source = av.open(str(path))
        if not source.streams.audio:
            source.close()
            return None
        in_stream = source.streams.audio[0]
        out_stream = container.add_stream_from_template(in_stream)
        return cls(source, in_stream, out_stream, container)

    def mux_until(self, t_s: float) -> None:
        while True:
            packet = self.pending if self.pending is not None else next(self.packets, None)
            self.pending = None
            if packet is None or packet.dts is None:
                if packet is None:
                    return
                continue
            if float((packet.pts - self.start) * packet.time_base) >= t_s:
                self.pending = packet  # belongs after the frames written so far
                return
            packet.pts -= self.start
            packet.dts -= self.start
            packet.stream = self.out_stream
            self.container.mux(packet)

    def close(self) -> None:
        self.source.close()


def _free_bytes(directory: Path) -> int | None:
    """Bytes available to us on the filesystem of ``directory`` (None when unknown)."""
    try:
        st = os.statvfs(directory)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize
