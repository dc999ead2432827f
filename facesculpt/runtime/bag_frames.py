"""What a bag stores of one message: its wire frames, optionally with the image compressed.

A recorded message is its frames exactly as they travelled (msgpack header + one frame per
array, ``facesculpt/msgs/codec.py``), so playback is byte-identical. In an MCAP bag (``bag.py``) each
message's data is these frames in the ``facesculpt-frames`` message encoding::

    u16 n_frames | (u8 codec | u32 frame_len | frame)*          little-endian

``codec`` is 0 for a raw frame; an Image's ``image`` array may be stored compressed
(1 = PNG, lossless; 2 = JPEG), in which case the frame holds the encoded image and is decoded
back to the raw array bytes on reading. An RGB-D frame's ``depth`` array (uint16 mm) stays raw
whatever the codec, left to the bag's chunk compression (lz4 by default): reading it back then
costs a fraction of decoding a 16-bit PNG, for a somewhat larger file. Bags written before store
it as a 16-bit PNG (3, lossless), still read. The channel's schema (encoding ``facesculpt-msgpack``,
named ``facesculpt.msgs.TYPE``) is the message type's field spec as JSON
(:func:`message_schema`), so a reader knows the type without importing the project.
"""

from __future__ import annotations

import dataclasses
import json
import struct
from dataclasses import dataclass

import msgpack
import numpy as np

from facesculpt.msgs.codec import REGISTRY, WIRE_VERSION

FRAMES_ENCODING = "facesculpt-frames"
SCHEMA_ENCODING = "facesculpt-msgpack"
SCHEMA_PREFIX = "facesculpt.msgs."
CODEC_RAW, CODEC_PNG, CODEC_JPEG, CODEC_PNG16 = 0, 1, 2, 3
CODECS = {"none": CODEC_RAW, "png": CODEC_PNG, "jpeg": CODEC_JPEG}
_COUNT = struct.Struct("<H")
_FRAME = struct.Struct("<BI")


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


def pack_frames(frames: list, header: dict, codec: int = CODEC_RAW, jpeg_quality: int = 95) -> bytes:
    """The ``facesculpt-frames`` bytes of ``frames``; ``codec`` applies to an Image's image array
    only (the depth array of an RGB-D frame stays raw, to the chunk compression)."""
    parts = [_COUNT.pack(len(frames))]
    for i, frame in enumerate(frames):
        kind, data = CODEC_RAW, frame
        if i > 0 and codec != CODEC_RAW and header.get("type") == "Image":
            name, _dtype, shape = header["a"][i - 1]
            if name == "image":
                kind, data = codec, encode_image(bytes(frame), shape, codec, jpeg_quality)
        parts.append(_FRAME.pack(kind, len(data)))
        parts.append(data)
    return b"".join(parts)


def unpack_frames(payload: bytes) -> list[bytes] | None:
    """The frames of a ``facesculpt-frames`` payload (compressed images decoded); None if malformed."""
    try:
        (n,) = _COUNT.unpack_from(payload, 0)
        pos, frames = _COUNT.size, []
        for _ in range(n):
            codec, flen = _FRAME.unpack_from(payload, pos)
            pos += _FRAME.size
            data = payload[pos:pos + flen]
            pos += flen
            if len(data) != flen:
                return None
            frames.append(data if codec == CODEC_RAW else decode_depth(data) if codec == CODEC_PNG16
                          else decode_image(data))
        return frames if pos == len(payload) else None
    except struct.error:
        return None


def encode_image(data: bytes, shape, codec: int, quality: int) -> bytes:
    """PNG (lossless) or JPEG bytes of an (H, W, 3) uint8 image given as raw bytes."""
    import cv2

    img = np.frombuffer(data, np.uint8).reshape(shape)
    if codec == CODEC_PNG:
        ok, enc = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    else:
        ok, enc = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise BagError("image compression failed")
    return enc.tobytes()


def decode_image(data: bytes) -> bytes:
    """The raw (H, W, 3) uint8 bytes of a PNG or JPEG image."""
    import cv2

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise BagError("a compressed image in the bag does not decode")
    return img.tobytes()


def encode_depth(data: bytes, shape) -> bytes:
    """16-bit PNG bytes of an (H, W) uint16 depth image given as raw bytes."""
    import cv2

    ok, enc = cv2.imencode(".png", np.frombuffer(data, np.uint16).reshape(shape), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise BagError("depth compression failed")
    return enc.tobytes()


def decode_depth(data: bytes) -> bytes:
    """The raw (H, W) uint16 bytes of a 16-bit PNG depth image."""
    import cv2

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None or img.dtype != np.uint16 or img.ndim != 2:
        raise BagError("a compressed depth image in the bag does not decode")
    return img.astype("<u2").tobytes()


def message_schema(type_name: str) -> bytes:
    """The JSON field spec of message type ``type_name`` (a channel's schema data).

    ``{"type", "wire_version", "frames": "header then one frame per present array",
    "scalars": {name: python type}, "arrays": {name: {"dtype", "shape", "optional"}}}``;
    a type this install does not know has only its name.
    """
    cls = REGISTRY.get(type_name)
    doc: dict = {"type": type_name, "wire_version": WIRE_VERSION,
                 "frames": "msgpack header {type, v, f: scalars, a: [[name, dtype, shape]]}, "
                           "then one frame of raw bytes per array listed in a"}
    if cls is not None:
        scalars, arrays = {}, {}
        for f in dataclasses.fields(cls):
            spec = f.metadata.get("array")
            if spec is None:
                scalars[f.name] = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
            else:
                arrays[f.name] = {"dtype": spec.dtype, "shape": list(spec.shape), "optional": spec.optional}
        doc.update(scalars=scalars, arrays=arrays)
    return json.dumps(doc, sort_keys=True).encode()


def type_of_schema(name: str) -> str:
    """The message type name of a schema name (``facesculpt.msgs.Image`` -> ``Image``)."""
    return name[len(SCHEMA_PREFIX):] if name.startswith(SCHEMA_PREFIX) else name
