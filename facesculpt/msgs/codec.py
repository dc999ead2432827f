"""Wire format of every message: the contract between nodes.

A message travels as one zmq multipart message::

    [topic (utf-8)] [header (msgpack)] [array 0 bytes] [array 1 bytes] ...

The header is a msgpack map ``{"type": str, "v": 1, "f": {scalar fields},
"a": [[name, dtype, shape], ...]}``; each array is its own frame, sent
without a copy and received with ``np.frombuffer`` (read-only views onto the
zmq frame). :func:`decode` validates everything against the message type and
raises :class:`DecodeError` for anything malformed; the node base drops and
counts such messages.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import msgpack
import numpy as np

WIRE_VERSION = 1
# A header is a few hundred bytes; anything far larger is garbage or an attack.
MAX_HEADER_BYTES = 1 << 20
MAX_ARRAYS = 64


class DecodeError(ValueError):
    """A message that does not match its declared type (dropped and counted by subscribers)."""


@dataclass(frozen=True)
class ArraySpec:
    """Declared dtype and shape of an array field.

    ``shape`` items are ints (fixed), strings (a dimension named the same in
    several fields must agree) or None (any size). ``optional`` fields may be None.
    """

    dtype: str
    shape: tuple
    optional: bool = False


def array(dtype: str, *shape, optional: bool = False):
    """Declare an array field of a message dataclass."""
    spec = ArraySpec(np.dtype(dtype).str, tuple(shape), optional)
    default = None if optional else _empty_default(spec)
    return field(default_factory=lambda: default if default is None else default.copy(),
                 metadata={"array": spec})


def _empty_default(spec: ArraySpec) -> np.ndarray:
    shape = tuple(d if isinstance(d, int) else 0 for d in spec.shape)
    if all(isinstance(d, int) for d in spec.shape) and len(spec.shape) == 2 and spec.shape[0] == spec.shape[1]:
        return np.eye(spec.shape[0], dtype=spec.dtype)  # square matrices (R, K) default to identity
    return np.zeros(shape, dtype=spec.dtype)


_SCALAR_TYPES = {int: (int,), float: (int, float), str: (str,), bool: (bool,), list: (list, tuple), dict: (dict,)}


@dataclass
class Message:
    """Base of every message type: source stamp, sequence number and frame id.

    ``stamp`` is in nanoseconds: the capture time of the camera frame the
    message derives from (``time.time_ns()`` clock), kept by every stage so
    latency can be measured end to end.
    """

    TYPE: ClassVar[str] = "Message"
    stamp: int = 0
    seq: int = 0
    frame_id: str = ""

    # -- schema -----------------------------------------------------------
    @classmethod
    def _schema(cls):
        cached = cls.__dict__.get("_schema_cache")
        if cached is None:
            arrays, scalars = [], []
            for f in dataclasses.fields(cls):
                if "array" in f.metadata:
                    arrays.append((f.name, f.metadata["array"]))
                else:
                    scalars.append((f.name, _scalar_type(f.type)))
            cached = (tuple(arrays), tuple(scalars))
            cls._schema_cache = cached
        return cached

    @classmethod
    def _decode_plan(cls):
        """What :func:`decode` checks, precomputed: ({array name: (dtype str, itemsize, shape)},
        ((scalar name, accepted types), ...), required array names)."""
        cached = cls.__dict__.get("_decode_plan_cache")
        if cached is None:
            arrays, scalars = cls._schema()
            cached = ({name: (spec.dtype, np.dtype(spec.dtype).itemsize, spec.shape) for name, spec in arrays},
                      scalars, tuple(name for name, spec in arrays if not spec.optional))
            cls._decode_plan_cache = cached
        return cached

    def check(self) -> None:
        """Rules of a message type beyond its fields' types (a value out of its set, ...): raise
        DecodeError. Override in a subclass; both :meth:`validate` and :func:`decode` call it."""

    def validate(self) -> None:
        """Raise DecodeError if a field does not match the declared type, or :meth:`check` fails."""
        self._checked_frames(build=False)

    # -- wire ---------------------------------------------------------------
    def to_frames(self) -> list:
        """Header + one buffer per array (contiguous; not copied), after the checks of
        :meth:`validate` (DecodeError): an invalid message never reaches the wire."""
        return self._checked_frames(build=True)

    def _checked_frames(self, build: bool) -> list | None:
        # Checking and framing in one pass: a publish runs this right after the message is made,
        # often on a thread just woken with cold caches, where every extra call shows in latency.
        arrays, scalars = self._schema()
        type_name = self.TYPE
        fields = {}
        for name, kinds in scalars:
            value = getattr(self, name)
            _check_scalar(type_name, name, value, kinds)
            fields[name] = value
        dims: dict[str, int] = {}
        meta, buffers = [], []
        for name, spec in arrays:
            value = getattr(self, name)
            _check_array(type_name, name, value, spec, dims)
            if build and value is not None:
                value = np.ascontiguousarray(value)
                meta.append([name, spec.dtype, list(value.shape)])
                buffers.append(memoryview(value).cast("B") if value.size else b"")
        self.check()
        if not build:
            return None
        header = {"type": type_name, "v": WIRE_VERSION, "f": fields, "a": meta}
        return [msgpack.packb(header, use_bin_type=True)] + buffers


def _scalar_type(annotation) -> tuple | None:
    # Annotations are strings under `from __future__ import annotations`.
    text = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", str(annotation))
    base = text.split("[")[0]
    for typ, kinds in _SCALAR_TYPES.items():
        if base == typ.__name__:
            return kinds
    return None


def _check_array(type_name: str, name: str, value, spec: ArraySpec, dims: dict) -> None:
    if value is None:
        if spec.optional:
            return
        raise DecodeError(f"{type_name}.{name}: missing array")
    if not isinstance(value, np.ndarray):
        raise DecodeError(f"{type_name}.{name}: expected ndarray, got {type(value).__name__}")
    if value.dtype.str != spec.dtype:
        raise DecodeError(f"{type_name}.{name}: dtype {value.dtype} != {np.dtype(spec.dtype)}")
    if value.ndim != len(spec.shape):
        raise DecodeError(f"{type_name}.{name}: {value.ndim} dims, expected {len(spec.shape)}")
    _check_shape(type_name, name, value.shape, spec.shape, dims)


def _check_scalar(type_name: str, name: str, value, kinds: tuple | None) -> None:
    if kinds is None or type(value) is kinds[0]:  # untyped, or exactly the declared type: the common case
        return
    if not isinstance(value, kinds) or kinds == (int,) and isinstance(value, bool):
        raise DecodeError(f"{type_name}.{name}: expected {kinds[0].__name__}, got {type(value).__name__}")


def _check_shape(type_name: str, name: str, shape: tuple, want_shape: tuple, dims: dict) -> None:
    """Fixed sizes match; a named dimension agrees with its earlier value in ``dims`` (recorded)."""
    for size, want in zip(shape, want_shape):
        if isinstance(want, int) and size != want:
            raise DecodeError(f"{type_name}.{name}: shape {shape} does not match {want_shape}")
        if isinstance(want, str) and dims.setdefault(want, size) != size:
            raise DecodeError(f"{type_name}.{name}: dimension {want}={size} disagrees with {dims[want]}")


REGISTRY: dict[str, type[Message]] = {}


def register(cls: type[Message]) -> type[Message]:
    """Class decorator adding a message type to the registry used by :func:`decode`."""
    REGISTRY[cls.TYPE] = cls
    return cls


def encode(msg: Message, topic: str) -> list:
    """Frames to send for ``msg`` on ``topic`` (validated first)."""
    return [topic.encode()] + msg.to_frames()


def decode_header(frame) -> dict:
    raw = bytes(frame.buffer if hasattr(frame, "buffer") else frame)
    if len(raw) > MAX_HEADER_BYTES:
        raise DecodeError(f"header of {len(raw)} bytes exceeds {MAX_HEADER_BYTES}")
    try:
        header = msgpack.unpackb(raw, raw=False, strict_map_key=True,
                                 max_bin_len=MAX_HEADER_BYTES, max_str_len=MAX_HEADER_BYTES)
    except Exception as exc:  # msgpack raises many types for garbage
        raise DecodeError(f"header is not msgpack: {exc.__class__.__name__}") from None
    if not isinstance(header, dict) or not isinstance(header.get("type"), str):
        raise DecodeError("header is not a message header")
    return header


def decode(frames: Sequence, expected: type[Message] | None = None) -> tuple[str, Message]:
    """Parse ``[topic, header, *arrays]`` (bytes or zmq.Frame) into ``(topic, message)``.

    Raises DecodeError for any mismatch: wrong frame count, unknown or
    unexpected type, wrong dtype/shape, truncated array bytes.
    """
    if len(frames) < 2 or len(frames) > MAX_ARRAYS + 2:
        raise DecodeError(f"{len(frames)} frames")
    try:
        topic = bytes(_buffer(frames[0])).decode()
    except UnicodeDecodeError:
        raise DecodeError("topic is not utf-8") from None
    header = decode_header(frames[1])
    cls = REGISTRY.get(header["type"])
    if cls is None:
        raise DecodeError(f"unknown message type {header['type']!r}")
    if expected is not None and cls is not expected:
        raise DecodeError(f"got {cls.TYPE} where {expected.TYPE} was expected")
    if header.get("v") != WIRE_VERSION:
        raise DecodeError(f"wire version {header.get('v')!r}")
    scalars_in, meta = header.get("f"), header.get("a")
    if not isinstance(scalars_in, dict) or not isinstance(meta, list):
        raise DecodeError("header lacks fields")
    if len(meta) != len(frames) - 2:
        raise DecodeError(f"header declares {len(meta)} arrays, {len(frames) - 2} frames came")
    # One pass that checks everything Message.validate() checks, so the message is built valid
    # and not checked twice: this runs on every message, right before its callback.
    array_plan, scalar_plan, required = cls._decode_plan()
    kwargs: dict[str, Any] = {}
    for name, kinds in scalar_plan:
        if name in scalars_in:
            value = scalars_in[name]
            _check_scalar(cls.TYPE, name, value, kinds)
            kwargs[name] = value
    dims: dict[str, int] = {}
    for entry, frame in zip(meta, frames[2:]):
        if not (isinstance(entry, list) and len(entry) == 3 and isinstance(entry[0], str)
                and isinstance(entry[1], str) and isinstance(entry[2], list)):
            raise DecodeError("malformed array descriptor")
        name, dtype, shape = entry
        plan = array_plan.get(name)
        if plan is None:
            raise DecodeError(f"{cls.TYPE} has no array {name!r}")
        want_dtype, itemsize, want_shape = plan
        if dtype != want_dtype or len(shape) != len(want_shape):
            raise DecodeError(f"{cls.TYPE}.{name}: bad descriptor {dtype} {shape}")
        nbytes = itemsize
        for size in shape:
            if type(size) is not int or not 0 <= size < 1 << 31:
                raise DecodeError(f"{cls.TYPE}.{name}: bad descriptor {dtype} {shape}")
            nbytes *= size
        _check_shape(cls.TYPE, name, tuple(shape), want_shape, dims)
        buf = _buffer(frame)
        if len(buf) != nbytes:
            raise DecodeError(f"{cls.TYPE}.{name}: {len(buf)} bytes for {nbytes} declared")
        kwargs[name] = np.frombuffer(buf, dtype=dtype).reshape(shape) if nbytes else np.zeros(shape, dtype)
    for name in required:
        if name not in kwargs:
            raise DecodeError(f"{cls.TYPE}.{name}: missing array")
    for name in array_plan:
        kwargs.setdefault(name, None)
    try:
        msg = cls(**kwargs)
    except TypeError as exc:
        raise DecodeError(str(exc)) from None
    msg.check()
    return topic, msg


def _buffer(frame) -> memoryview:
    if hasattr(frame, "buffer"):
        return frame.buffer
    return memoryview(frame)


def summarize(msg: Message) -> dict:
    """JSON-friendly view of a message: scalars as they are, arrays as shape/dtype/min/max."""
    arrays, scalars = msg._schema()
    out: dict[str, Any] = {"type": msg.TYPE}
    for name, _ in scalars:
        out[name] = getattr(msg, name)
    for name, _ in arrays:
        value = getattr(msg, name)
        if value is None:
            out[name] = None
        elif value.size == 0:
            out[name] = {"shape": list(value.shape), "dtype": str(value.dtype)}
        else:
            out[name] = {"shape": list(value.shape), "dtype": str(value.dtype),
                         "min": float(np.nanmin(value)), "max": float(np.nanmax(value))}
    return out
