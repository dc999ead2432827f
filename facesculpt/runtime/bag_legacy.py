"""The bag format before MCAP (``FSBAG001``): still read, so older recordings still play.

Layout::

    b"FSBAG001"                                   file magic (8 bytes)
    record*                                       one per message, appended as received
    record := u32 length | u32 crc32(body) | body[length]
    body   := u64 receive_time_ns | u16 topic_len | topic | u16 n_frames
              | (u8 codec | u32 frame_len | frame)*

The frames part is the ``facesculpt-frames`` encoding of ``bag_frames.py``. A reader stops at
the first incomplete or corrupt record, so a file cut off at any byte still yields every
complete record before it. :class:`LegacyBagWriter` writes this format (tests make old bags
with it); ``facesculpt bag record`` writes MCAP.
"""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path

import msgpack

from .bag_frames import CODECS, BagError, Record, pack_frames, unpack_frames

LEGACY_MAGIC = b"FSBAG001"
MAX_RECORD = 1 << 30
_HEAD = struct.Struct("<II")


class LegacyBagWriter:
    """Appends records in the old format; ``compression`` in none|png|jpeg applies to Image arrays."""

    def __init__(self, path: str | os.PathLike, compression: str = "none", jpeg_quality: int = 95):
        self.path = Path(path)
        self.codec = CODECS[compression]
        self.jpeg_quality = int(jpeg_quality)
        self.count = 0
        try:
            self.file = open(self.path, "wb")
            self.file.write(LEGACY_MAGIC)
        except OSError as exc:
            raise BagError(f"cannot write bag {self.path}: {exc.strerror}") from None

    def write(self, time_ns: int, topic: str, frames: list) -> None:
        header = msgpack.unpackb(bytes(frames[0]), raw=False)
        tb = topic.encode()
        payload = (struct.pack("<QH", int(time_ns), len(tb)) + tb
                   + pack_frames(frames, header, self.codec, self.jpeg_quality))
        self.file.write(_HEAD.pack(len(payload), zlib.crc32(payload)))
        self.file.write(payload)
        self.file.flush()
        self.count += 1

    def close(self) -> None:
        self.file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def legacy_records(path: Path, size: int, progress: dict) -> Iterator[Record]:
    """The complete records of an old-format bag in order; ``progress["good_end"]`` is the
    byte offset after the last complete one (updated as they are read)."""
    with open(path, "rb") as f:
        f.seek(len(LEGACY_MAGIC))
        progress["good_end"] = f.tell()
        while True:
            head = f.read(_HEAD.size)
            if len(head) < _HEAD.size:
                return
            length, crc = _HEAD.unpack(head)
            if length > MAX_RECORD:
                return
            payload = f.read(length)
            if len(payload) < length or zlib.crc32(payload) != crc:
                return
            record = _parse(payload)
            if record is None:
                return
            progress["good_end"] = f.tell()
            yield record


def _parse(payload: bytes) -> Record | None:
    try:
        time_ns, tlen = struct.unpack_from("<QH", payload, 0)
        topic = payload[10:10 + tlen].decode()
    except (struct.error, UnicodeDecodeError):
        return None
    frames = unpack_frames(payload[10 + tlen:])
    return None if frames is None else Record(time_ns, topic, frames)
