"""Bag files: recordings of messages as MCAP, replayable into a graph.

MCAP (https://mcap.dev, the ROS 2 default bag format) with the ``mcap`` library: messages go
into chunks, compressed (lz4 by default, cheap enough to keep up with a live camera; zstd is
smaller for more CPU; or none), each followed by its message index; closing the file writes
the summary section (schemas, channels, statistics, chunk indexes), so ``bag info`` reads the
summary alone and playing from a time or a topic reads only the chunks the indexes name. One
channel per topic, in the ``facesculpt-frames`` message encoding, with the message type's
schema (``bag_frames.py``): a message's data is its frames exactly as they travelled, so
playback is byte-identical. ``log_time`` is the receive time, ``publish_time`` the message's
stamp, ``sequence`` its seq.

A chunk reaches the disk when it holds ``chunk_bytes`` or is ``chunk_s`` old, so a recorder
killed without a chance to close its file loses at most that; a file cut off at any byte (no
summary) is read record by record from the start up to the last complete one (chunks whose
CRC fails or that end past the cut are not used), which yields every message of every
complete chunk. Bags in the format before MCAP (``bag_legacy.py``) are told by their magic
bytes and read as before. Messages of channels that are not facesculpt's (another tool's
MCAP) are counted and listed by :func:`bag_info`, and skipped by playback.
"""

from __future__ import annotations

import io
import os
import struct
import time
from collections.abc import Iterator
from pathlib import Path

import msgpack
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer

from .bag_frames import (
    CODECS,
    FRAMES_ENCODING,
    SCHEMA_ENCODING,
    SCHEMA_PREFIX,
    BagError,
    Record,
    message_schema,
    pack_frames,
    type_of_schema,
    unpack_frames,
)
from .bag_legacy import LEGACY_MAGIC, legacy_records

__all__ = ["BagError", "BagReader", "BagWriter", "Record", "bag_info", "MAGIC", "LEGACY_MAGIC"]

MAGIC = b"\x89MCAP0\r\n"
CHUNK_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
_RECORD_HEAD = struct.Struct("<BQ")


class BagWriter:
    """Writes an MCAP bag. ``compression`` (none|png|jpeg) applies to Image arrays only;
    ``chunk_compression`` (lz4|zstd|none) to every chunk; a chunk is written when it holds
    ``chunk_bytes`` bytes or its first message is ``chunk_s`` seconds old.

    ``count`` is the number of messages on disk (in written chunks), ``bytes`` the file's
    length up to the end of the last written chunk.
    """

    def __init__(self, path: str | os.PathLike, compression: str = "none", jpeg_quality: int = 95,
                 chunk_compression: str = "lz4", chunk_bytes: int = 1 << 20, chunk_s: float = 0.5):
        if compression not in CODECS:
            raise BagError(f"unknown compression {compression!r} (choose from {', '.join(CODECS)})")
        if chunk_compression not in CHUNK_COMPRESSION:
            raise BagError(f"unknown chunk compression {chunk_compression!r} "
                           f"(choose from {', '.join(CHUNK_COMPRESSION)})")
        self.path = Path(path)
        self.codec = CODECS[compression]
        self.jpeg_quality = int(jpeg_quality)
        self.chunk_s = float(chunk_s)
        self.count = self.pending = 0
        self.bytes = 0
        self.failed = False
        self._chunk_started = 0.0
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        try:
            self.file = open(self.path, "wb")
            self.writer = Writer(self.file, chunk_size=int(chunk_bytes),
                                 compression=CHUNK_COMPRESSION[chunk_compression])
            self.writer.start(profile="", library="facesculpt")
            self._landed()
        except OSError as exc:
            raise BagError(f"cannot write bag {self.path}: {exc.strerror}") from None

    def write(self, time_ns: int, topic: str, frames: list) -> None:
        """Add one message (its wire frames ``[header, *arrays]``) received at ``time_ns``."""
        if self.failed:
            raise BagError(f"bag {self.path} failed earlier; nothing more is written")
        header = msgpack.unpackb(bytes(frames[0]), raw=False)
        fields = header.get("f") if isinstance(header.get("f"), dict) else {}
        stamp, seq = fields.get("stamp"), fields.get("seq")
        payload = pack_frames(frames, header, self.codec, self.jpeg_quality)
        try:
            channel = self._channel(topic, str(header.get("type", "")))
            if not self.pending:
                self._chunk_started = time.monotonic()
            self.writer.add_message(channel, log_time=int(time_ns), data=payload,
                                    publish_time=int(stamp) if isinstance(stamp, int) and stamp >= 0 else int(time_ns),
                                    sequence=seq & 0xFFFFFFFF if isinstance(seq, int) else 0)
            self.pending += 1
            self._check_landed()
            self.flush_if_due()
        except OSError as exc:
            self.failed = True
            raise BagError(f"writing bag {self.path} failed after {self.count} records: {exc.strerror}") from None

    def _channel(self, topic: str, type_name: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            schema = self._schemas.get(type_name)
            if schema is None:
                schema = self.writer.register_schema(SCHEMA_PREFIX + type_name, SCHEMA_ENCODING,
                                                     message_schema(type_name))
                self._schemas[type_name] = schema
            meta = {"image_compression": next(k for k, v in CODECS.items() if v == self.codec)}
            channel = self.writer.register_channel(topic, FRAMES_ENCODING, schema, meta)
            self._channels[topic] = channel
            self._check_landed()
        return channel

    def flush_if_due(self) -> None:
        """Write the chunk in progress if its first message is ``chunk_s`` old (call it now and
        then while no message comes, so a quiet topic's last messages reach the disk)."""
        if self.pending and not self.failed and time.monotonic() - self._chunk_started >= self.chunk_s:
            try:
                self.writer.flush()
                self._check_landed()
            except OSError as exc:
                self.failed = True
                raise BagError(f"writing bag {self.path} failed after {self.count} records: {exc.strerror}") from None

    def _check_landed(self) -> None:
        if self.file.tell() != self.bytes:  # the writer wrote a chunk: every pending message is in it
            self._landed()

    def _landed(self) -> None:
        self.file.flush()
        self.bytes = self.file.tell()
        self.count += self.pending
        self.pending = 0

    def close(self) -> None:
        """Write the last chunk and the summary, close; after a failed write (disk full), cut the
        file back to the end of the last chunk written whole."""
        if not self.failed:
            try:
                self.writer.flush()
                self._check_landed()
                self.writer.finish()
            except OSError:
                self.failed = True
        try:
            self.file.close()
        except OSError:
            self.failed = True
        if self.failed:
            try:
                os.truncate(self.path, self.bytes)
            except OSError:
                pass  # the reader stops at the incomplete record anyway

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class BagReader:
    """The messages of a bag (MCAP, or the format before it), in the order they were written.

    Iterating yields :class:`Record` for every facesculpt message; :meth:`messages` can start at
    a time or keep some topics. ``ignored_bytes`` says how much of a file cut mid-write followed
    its last complete record; ``foreign`` counts the messages of channels that are not
    facesculpt's by topic.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"bag {self.path} not found")
        with open(self.path, "rb") as f:
            magic = f.read(len(MAGIC))
            self.size = f.seek(0, io.SEEK_END)
            f.seek(max(0, self.size - len(MAGIC)))
            tail = f.read(len(MAGIC))
        if magic == LEGACY_MAGIC:
            self.format = "facesculpt-legacy"
        elif magic == MAGIC:
            self.format = "mcap"
        else:
            raise BagError(f"{self.path} is not a facesculpt bag (bad magic: neither MCAP nor the older format)")
        self.summary = self._read_summary() if self.format == "mcap" and tail == MAGIC else None
        self.ignored_bytes = 0
        self.records_read = 0
        self.foreign: dict[str, int] = {}

    def _read_summary(self):
        try:
            with open(self.path, "rb") as f:
                return SeekingReader(f).get_summary()
        except Exception:  # a footer that does not parse: read the file record by record instead
            return None

    def __iter__(self) -> Iterator[Record]:
        return self.messages()

    def messages(self, start_ns: int | None = None, topics=None) -> Iterator[Record]:
        """Records received at or after ``start_ns`` on ``topics`` (None: all)."""
        self.records_read = 0
        self.foreign = {}
        wanted = None if topics is None else set([topics] if isinstance(topics, str) else topics)
        if self.format != "mcap":
            for rec in self._legacy():
                if (start_ns is None or rec.time_ns >= start_ns) and (wanted is None or rec.topic in wanted):
                    self.records_read += 1
                    yield rec
            return
        for channel, _schema, message in self._raw(start_ns, wanted):
            frames = unpack_frames(message.data) if channel.message_encoding == FRAMES_ENCODING else None
            if frames is None:
                self.foreign[channel.topic] = self.foreign.get(channel.topic, 0) + 1
                continue
            self.records_read += 1
            yield Record(message.log_time, channel.topic, frames)

    def _legacy(self) -> Iterator[Record]:
        progress = {"good_end": len(LEGACY_MAGIC)}
        try:
            for rec in legacy_records(self.path, self.size, progress):
                self.ignored_bytes = self.size - progress["good_end"]
                yield rec
        finally:
            self.ignored_bytes = self.size - progress["good_end"]

    def _raw(self, start_ns=None, wanted=None) -> Iterator[tuple[Channel, Schema | None, Message]]:
        """(channel, schema, message) of every message of an MCAP bag in file order."""
        if self.summary is not None and self.summary.chunk_indexes and self.summary.channels:
            yield from self._raw_indexed(start_ns, wanted)
        else:
            yield from self._raw_scan(start_ns, wanted)

    def _raw_indexed(self, start_ns, wanted):
        summary = self.summary
        ids = None if wanted is None else {i for i, c in summary.channels.items() if c.topic in wanted}
        chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
        with open(self.path, "rb") as f:
            for index in chunks:
                if start_ns is not None and index.message_end_time < start_ns:
                    continue
                if ids is not None and index.message_index_offsets and not ids & set(index.message_index_offsets):
                    continue
                f.seek(index.chunk_start_offset)
                records = _parse_record(f.read(index.chunk_length))
                if records is None:
                    raise BagError(f"{self.path}: the chunk at byte {index.chunk_start_offset} does not decode")
                for rec in records:
                    channel = summary.channels.get(getattr(rec, "channel_id", None))
                    if isinstance(rec, Message) and channel is not None and _keep(rec, start_ns, ids):
                        yield channel, summary.schemas.get(channel.schema_id), rec

    def _raw_scan(self, start_ns, wanted):
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        good_end = len(MAGIC)
        self.ignored_bytes = self.size - good_end
        with open(self.path, "rb") as f:
            f.seek(good_end)
            while True:
                head = f.read(_RECORD_HEAD.size)
                if len(head) < _RECORD_HEAD.size:
                    break
                opcode, length = _RECORD_HEAD.unpack(head)
                if length > self.size - f.tell():
                    break
                records = _parse_record(head + f.read(length))
                if records is None:
                    break
                good_end = f.tell()
                if opcode == Opcode.FOOTER and f.read(len(MAGIC)) == MAGIC:
                    good_end = f.tell()
                self.ignored_bytes = self.size - good_end
                for rec in records:
                    if isinstance(rec, Schema):
                        schemas[rec.id] = rec
                    elif isinstance(rec, Channel):
                        channels[rec.id] = rec
                    elif isinstance(rec, Message) and rec.channel_id in channels:
                        channel = channels[rec.channel_id]
                        if _keep(rec, start_ns, None) and (wanted is None or channel.topic in wanted):
                            yield channel, schemas.get(channel.schema_id), rec
                if opcode == Opcode.FOOTER:
                    break

    def topics(self) -> dict[str, str]:
        """{topic: message type} of the facesculpt channels (from the summary when there is one)."""
        if self.summary is not None and self.summary.statistics is not None:
            out, counts = {}, self.summary.statistics.channel_message_counts
            for cid, channel in self.summary.channels.items():
                if channel.message_encoding == FRAMES_ENCODING and counts.get(cid):
                    schema = self.summary.schemas.get(channel.schema_id)
                    out[channel.topic] = type_of_schema(schema.name) if schema else "?"
            return out
        out = {}
        for rec in self.messages():
            if rec.topic not in out:
                out[rec.topic] = _header_type(rec)
        return out

    def start_ns(self) -> int | None:
        """The receive time of the first message (None for an empty bag)."""
        if self.summary is not None and self.summary.statistics is not None:
            return self.summary.statistics.message_start_time if self.summary.statistics.message_count else None
        for rec in self.messages():
            return rec.time_ns
        return None


def _keep(message: Message, start_ns, ids) -> bool:
    return (start_ns is None or message.log_time >= start_ns) and (ids is None or message.channel_id in ids)


def _parse_record(raw: bytes) -> list | None:
    """The records in one whole top-level MCAP record (a chunk's, CRC-checked); [] for a kind
    that carries no message; None if it does not decode."""
    opcode, length = _RECORD_HEAD.unpack_from(raw, 0)
    stream = ReadDataStream(io.BytesIO(raw[_RECORD_HEAD.size:]))
    try:
        if opcode == Opcode.CHUNK:
            return breakup_chunk(Chunk.read(stream), validate_crc=True)
        if opcode == Opcode.MESSAGE:
            return [Message.read(stream, length)]
        if opcode == Opcode.SCHEMA:
            return [Schema.read(stream)]
        if opcode == Opcode.CHANNEL:
            return [Channel.read(stream)]
        return []
    except Exception:  # truncated, corrupt (CRC), or compressed with something this install lacks
        return None


def _header_type(rec: Record) -> str:
    try:
        return str(rec.header.get("type", "?"))
    except Exception:
        return "?"


def bag_info(path: str | os.PathLike) -> dict:
    """Topics (count, types), duration, how many trailing bytes were not a complete record, and
    ``undecodable``: one sentence on the channels it cannot decode (None when there are none).
    A complete MCAP file is described from its summary section alone."""
    reader = BagReader(path)
    tally = _Tally()
    summary = reader.summary
    if summary is not None and summary.statistics is not None:
        stats = summary.statistics
        for cid, n in stats.channel_message_counts.items():
            channel = summary.channels[cid]
            schema = summary.schemas.get(channel.schema_id)
            tally.add(channel, schema, type_of_schema(schema.name) if schema else "?", n)
        if stats.message_count:
            tally.records = stats.message_count
            tally.first, tally.last = stats.message_start_time, stats.message_end_time
    elif reader.format != "mcap":
        legacy = Channel(0, "", FRAMES_ENCODING, 0, {})
        for rec in reader:
            legacy.topic = rec.topic
            tally.add(legacy, None, _header_type(rec), 1, rec.time_ns)
    else:
        for channel, schema, message in reader._raw():
            frames = unpack_frames(message.data) if channel.message_encoding == FRAMES_ENCODING else None
            typ = _header_type(Record(0, "", frames)) if frames else schema.name if schema else "?"
            tally.add(channel, schema, typ, 1, message.log_time)
    first, last = tally.first, tally.last
    return {
        "path": str(reader.path), "bytes": reader.size, "format": reader.format,
        "indexed": summary is not None, "records": tally.records, "ignored_bytes": reader.ignored_bytes,
        "start_ns": first, "end_ns": last,
        "duration_s": 0.0 if first is None else round((last - first) / 1e9, 3),
        "topics": {t: {"count": e["count"], "types": sorted(e["types"])} for t, e in sorted(tally.topics.items())},
        "undecodable": _undecodable_sentence(tally.foreign, tally.topics),
    }


class _Tally:
    """What bag_info counts: per topic, the messages and their types; the foreign channels."""

    def __init__(self):
        self.topics: dict[str, dict] = {}
        self.foreign: dict[str, str] = {}
        self.records = 0
        self.first = self.last = None

    def add(self, channel: Channel, schema: Schema | None, type_name: str, n: int, time_ns: int | None = None):
        entry = self.topics.setdefault(channel.topic, {"count": 0, "types": set()})
        entry["count"] += n
        entry["types"].add(type_name)
        if channel.message_encoding != FRAMES_ENCODING:
            self.foreign[channel.topic] = _describe(channel, schema)
        if time_ns is not None:
            self.records += n
            self.first = time_ns if self.first is None else min(self.first, time_ns)
            self.last = time_ns if self.last is None else max(self.last, time_ns)


def _describe(channel: Channel, schema: Schema | None) -> str:
    kind = f"schema {schema.name!r} ({schema.encoding or 'no schema encoding'})" if schema else "no schema"
    return f"{channel.topic} ({channel.message_encoding or 'no encoding'}, {kind})"


def _undecodable_sentence(foreign: dict[str, str], topics: dict) -> str | None:
    if not foreign:
        return None
    n = sum(topics[t]["count"] for t in foreign)
    return (f"{n} messages on {len(foreign)} channel{'s' if len(foreign) > 1 else ''} are not facesculpt "
            f"messages and cannot be decoded or played: {'; '.join(foreign[t] for t in sorted(foreign))}.")
