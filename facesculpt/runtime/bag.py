"""Bag files: append-only recordings of messages, replayable into a graph.

Layout::

    b"FSBAG001"                                   file magic (8 bytes)
    record*                                       one per message, appended as received
    record := u32 length | u32 crc32(body) | body[length]
    body   := u64 receive_time_ns | u16 topic_len | topic | u16 n_frames
              | (u8 codec | u32 frame_len | frame)*

A record holds the message's frames exactly as they travelled (msgpack header
+ one frame per array), so playback is byte-identical. ``codec`` is 0 for raw
frames; images may be stored compressed (1 = PNG, lossless; 2 = JPEG), in
which case the frame holds the encoded image and the header is rewritten
on playback. A reader stops at the first incomplete or corrupt record, so a
file cut off at any byte still yields every complete record before the cut.
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import msgpack
import numpy as np

MAGIC = b"FSBAG001"
CODEC_RAW, CODEC_PNG, CODEC_JPEG = 0, 1, 2
CODECS = {"none": CODEC_RAW, "png": CODEC_PNG, "jpeg": CODEC_JPEG}
MAX_RECORD = 1 << 30
_HEAD = struct.Struct("<II")


class BagError(ValueError):
    """A file that is not a bag, or a write that failed."""


@dataclass
class Record:
    """One recorded message: receive time (ns), topic, and its frames ``[header, *arrays]``."""

    time_ns: int
    topic: str
    frames: list[bytes]

    @property
    def header(self) -> dict:
        return msgpack.unpackb(self.frames[0], raw=False)


class BagWriter:
    """Appends records; ``compression`` in none|png|jpeg applies to Image arrays only."""

    def __init__(self, path: str | os.PathLike, compression: str = "none", jpeg_quality: int = 95):
        if compression not in CODECS:
            raise BagError(f"unknown compression {compression!r} (choose from {', '.join(CODECS)})")
        self.path = Path(path)
        self.codec = CODECS[compression]
        self.jpeg_quality = int(jpeg_quality)
        self.count = 0
        self.bytes = 0
        self.failed = False
        try:
            self.file: BinaryIO = open(self.path, "wb")
            self.file.write(MAGIC)
        except OSError as exc:
            raise BagError(f"cannot write bag {self.path}: {exc.strerror}") from None

    def write(self, time_ns: int, topic: str, frames: list) -> None:
        header = msgpack.unpackb(bytes(frames[0]), raw=False)
        body = io.BytesIO()
        tb = topic.encode()
        body.write(struct.pack("<QH", int(time_ns), len(tb)))
        body.write(tb)
        body.write(struct.pack("<H", len(frames)))
        for i, frame in enumerate(frames):
            codec, data = CODEC_RAW, bytes(frame)
            if i > 0 and self.codec != CODEC_RAW and header.get("type") == "Image":
                name, dtype, shape = header["a"][i - 1]
                if name == "image":
                    codec, data = self.codec, _encode_image(data, shape, self.codec, self.jpeg_quality)
            body.write(struct.pack("<BI", codec, len(data)))
            body.write(data)
        payload = body.getvalue()
        try:
            self.file.write(_HEAD.pack(len(payload), zlib.crc32(payload)))
            self.file.write(payload)
            self.file.flush()
        except OSError as exc:
            self.failed = True
            raise BagError(f"writing bag {self.path} failed after {self.count} records: {exc.strerror}") from None
        self.count += 1
        self.bytes += len(payload) + _HEAD.size

    def close(self) -> None:
        """Close the file; after a failed write (disk full), cut it back to the last whole record."""
        try:
            self.file.close()
        except OSError:
            self.failed = True
        if self.failed:
            try:
                os.truncate(self.path, len(MAGIC) + self.bytes)
            except OSError:
                pass  # the reader stops at the incomplete record anyway

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _encode_image(data: bytes, shape, codec: int, quality: int) -> bytes:
    import cv2

    img = np.frombuffer(data, np.uint8).reshape(shape)
    if codec == CODEC_PNG:
        ok, enc = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    else:
        ok, enc = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise BagError("image compression failed")
    return enc.tobytes()


def _decode_image(data: bytes) -> bytes:
    import cv2

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise BagError("a compressed image in the bag does not decode")
    return img.tobytes()


class BagReader:
    """Iterates the complete records of a bag; ``ignored_bytes`` tells what followed the last one."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"bag {self.path} not found")
        with open(self.path, "rb") as f:
            if f.read(len(MAGIC)) != MAGIC:
                raise BagError(f"{self.path} is not a facesculpt bag (bad magic)")
        self.size = self.path.stat().st_size
        self.ignored_bytes = 0
        self.records_read = 0

    def __iter__(self) -> Iterator[Record]:
        with open(self.path, "rb") as f:
            f.seek(len(MAGIC))
            good_end = f.tell()
            self.records_read = 0
            while True:
                head = f.read(_HEAD.size)
                if len(head) < _HEAD.size:
                    break
                length, crc = _HEAD.unpack(head)
                if length > MAX_RECORD:
                    break
                payload = f.read(length)
                if len(payload) < length or zlib.crc32(payload) != crc:
                    break
                record = _parse(payload)
                if record is None:
                    break
                good_end = f.tell()
                self.records_read += 1
                self.ignored_bytes = self.size - good_end
                yield record
            self.ignored_bytes = self.size - good_end


def _parse(payload: bytes) -> Record | None:
    try:
        time_ns, tlen = struct.unpack_from("<QH", payload, 0)
        pos = 10
        topic = payload[pos:pos + tlen].decode()
        pos += tlen
        (n,) = struct.unpack_from("<H", payload, pos)
        pos += 2
        frames = []
        for _ in range(n):
            codec, flen = struct.unpack_from("<BI", payload, pos)
            pos += 5
            data = payload[pos:pos + flen]
            pos += flen
            if len(data) != flen:
                return None
            frames.append(data if codec == CODEC_RAW else _decode_image(data))
        return Record(time_ns, topic, frames) if pos == len(payload) else None
    except (struct.error, UnicodeDecodeError):
        return None


def bag_info(path: str | os.PathLike) -> dict:
    """Topics, counts, types, duration, and how many trailing bytes were not a complete record."""
    reader = BagReader(path)
    topics: dict[str, dict] = {}
    first = last = None
    for rec in reader:
        first = rec.time_ns if first is None else first
        last = rec.time_ns
        try:
            typ = rec.header.get("type", "?")
        except Exception:
            typ = "?"
        entry = topics.setdefault(rec.topic, {"count": 0, "types": set()})
        entry["count"] += 1
        entry["types"].add(typ)
    return {
        "path": str(reader.path), "bytes": reader.size, "records": reader.records_read,
        "ignored_bytes": reader.ignored_bytes,
        "start_ns": first, "end_ns": last,
        "duration_s": 0.0 if first is None else round((last - first) / 1e9, 3),
        "topics": {t: {"count": e["count"], "types": sorted(e["types"])} for t, e in sorted(topics.items())},
    }
