"""A minimal reader of TensorFlow Lite model files (the FlatBuffers ``schema.fbs`` of TFLite).

It reads exactly what the converter needs from the first subgraph: tensors (name, shape,
type, constant data), operators (name, inputs, outputs, builtin options) and the graph's
inputs and outputs. No dependency beyond numpy: FlatBuffers is a simple format, decoded
here with ``struct``.

FlatBuffers in brief: a table starts with an int32 offset back to its vtable; the vtable
holds uint16 byte offsets of the fields inside the table (0 = absent, use the default);
vectors and strings are reached through uint32 offsets relative to where the offset is
stored and begin with a uint32 length.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

# TensorType enum of schema.fbs -> numpy dtype.
TENSOR_TYPES = {
    0: np.dtype(np.float32),
    1: np.dtype(np.float16),
    2: np.dtype(np.int32),
    3: np.dtype(np.uint8),
    4: np.dtype(np.int64),
    6: np.dtype(np.bool_),
    7: np.dtype(np.int16),
    9: np.dtype(np.int8),
    10: np.dtype(np.float64),
}

# BuiltinOperator enum of schema.fbs (the first 64 codes; others are named BUILTIN_<code>).
BUILTIN_OPERATORS = [
    "ADD", "AVERAGE_POOL_2D", "CONCATENATION", "CONV_2D", "DEPTHWISE_CONV_2D", "DEPTH_TO_SPACE",
    "DEQUANTIZE", "EMBEDDING_LOOKUP", "FLOOR", "FULLY_CONNECTED", "HASHTABLE_LOOKUP",
    "L2_NORMALIZATION", "L2_POOL_2D", "LOCAL_RESPONSE_NORMALIZATION", "LOGISTIC", "LSH_PROJECTION",
    "LSTM", "MAX_POOL_2D", "MUL", "RELU", "RELU_N1_TO_1", "RELU6", "RESHAPE", "RESIZE_BILINEAR",
    "RNN", "SOFTMAX", "SPACE_TO_DEPTH", "SVDF", "TANH", "CONCAT_EMBEDDINGS", "SKIP_GRAM", "CALL",
    "CUSTOM", "EMBEDDING_LOOKUP_SPARSE", "PAD", "UNIDIRECTIONAL_SEQUENCE_RNN", "GATHER",
    "BATCH_TO_SPACE_ND", "SPACE_TO_BATCH_ND", "TRANSPOSE", "MEAN", "SUB", "DIV", "SQUEEZE",
    "UNIDIRECTIONAL_SEQUENCE_LSTM", "STRIDED_SLICE", "BIDIRECTIONAL_SEQUENCE_RNN", "EXP", "TOPK_V2",
    "SPLIT", "LOG_SOFTMAX", "DELEGATE", "BIDIRECTIONAL_SEQUENCE_LSTM", "CAST", "PRELU", "MAXIMUM",
    "ARG_MAX", "MINIMUM", "LESS", "NEG", "PADV2", "GREATER", "GREATER_EQUAL", "LESS_EQUAL",
]
# Later codes the converted networks use, by name.
LATER_OPERATORS = {117: "HARD_SWISH"}

# Builtin options tables we decode: operator -> [(field, struct format, default)] in slot order.
_PADDING = "padding"  # Padding enum: 0 SAME, 1 VALID
_OPTION_FIELDS: dict[str, list[tuple[str, str, object]]] = {
    "CONV_2D": [(_PADDING, "b", 0), ("stride_w", "i", 1), ("stride_h", "i", 1),
                ("fused_activation_function", "b", 0), ("dilation_w_factor", "i", 1),
                ("dilation_h_factor", "i", 1)],
    "DEPTHWISE_CONV_2D": [(_PADDING, "b", 0), ("stride_w", "i", 1), ("stride_h", "i", 1),
                          ("depth_multiplier", "i", 0), ("fused_activation_function", "b", 0),
                          ("dilation_w_factor", "i", 1), ("dilation_h_factor", "i", 1)],
    "MAX_POOL_2D": [(_PADDING, "b", 0), ("stride_w", "i", 1), ("stride_h", "i", 1),
                    ("filter_width", "i", 1), ("filter_height", "i", 1),
                    ("fused_activation_function", "b", 0)],
    "AVERAGE_POOL_2D": [(_PADDING, "b", 0), ("stride_w", "i", 1), ("stride_h", "i", 1),
                        ("filter_width", "i", 1), ("filter_height", "i", 1),
                        ("fused_activation_function", "b", 0)],
    "ADD": [("fused_activation_function", "b", 0)],
    "MUL": [("fused_activation_function", "b", 0)],
    "SUB": [("fused_activation_function", "b", 0)],
    "CONCATENATION": [("axis", "i", 0), ("fused_activation_function", "b", 0)],
    "RESHAPE": [("new_shape", "[i", None)],
    "FULLY_CONNECTED": [("fused_activation_function", "b", 0), ("weights_format", "b", 0),
                        ("keep_num_dims", "b", 0), ("asymmetric_quantize_inputs", "b", 0)],
    "MEAN": [("keep_dims", "b", 0)],
    "RESIZE_BILINEAR": [("new_height", "i", 0), ("new_width", "i", 0), ("align_corners", "b", 0),
                        ("half_pixel_centers", "b", 0)],
}

PADDING_NAMES = {0: "SAME", 1: "VALID"}
ACTIVATION_NAMES = {0: "NONE", 1: "RELU", 2: "RELU_N1_TO_1", 3: "RELU6", 4: "TANH", 5: "SIGN_BIT"}


class TfliteFormatError(ValueError):
    """The bytes are not a TFLite model this reader understands."""


@dataclass
class Tensor:
    """One tensor of the graph: ``data`` is the constant content (None for activations)."""

    index: int
    name: str
    shape: tuple[int, ...]
    dtype: np.dtype
    data: np.ndarray | None = None


@dataclass
class Operator:
    """One operator: ``name`` is the builtin operator name (or the custom code);
    ``custom_options`` a custom operator's raw option bytes (its own format)."""

    name: str
    inputs: list[int]
    outputs: list[int]
    options: dict = field(default_factory=dict)
    custom: bool = False
    custom_options: bytes = b""


@dataclass
class TfliteGraph:
    """The first subgraph of a TFLite model, in execution order."""

    tensors: list[Tensor]
    operators: list[Operator]
    inputs: list[int]
    outputs: list[int]
    version: int
    description: str


class _Table:
    """A FlatBuffers table at byte position ``pos`` of ``buf``."""

    __slots__ = ("buf", "pos", "_vt", "_vt_len")

    def __init__(self, buf: bytes, pos: int):
        self.buf = buf
        self.pos = pos
        if pos < 0 or pos + 4 > len(buf):
            raise TfliteFormatError(f"table offset {pos} outside the file")
        self._vt = pos - struct.unpack_from("<i", buf, pos)[0]
        if self._vt < 0 or self._vt + 4 > len(buf):
            raise TfliteFormatError(f"vtable offset {self._vt} outside the file")
        self._vt_len = struct.unpack_from("<H", buf, self._vt)[0]

    def _field(self, slot: int) -> int:
        """Byte position of field ``slot`` or 0 when absent."""
        entry = 4 + 2 * slot
        if entry >= self._vt_len:
            return 0
        rel = struct.unpack_from("<H", self.buf, self._vt + entry)[0]
        return self.pos + rel if rel else 0

    def scalar(self, slot: int, fmt: str, default=0):
        p = self._field(slot)
        return struct.unpack_from("<" + fmt, self.buf, p)[0] if p else default

    def _indirect(self, p: int) -> int:
        return p + struct.unpack_from("<I", self.buf, p)[0]

    def table(self, slot: int) -> _Table | None:
        p = self._field(slot)
        return _Table(self.buf, self._indirect(p)) if p else None

    def string(self, slot: int) -> str:
        p = self._field(slot)
        if not p:
            return ""
        start = self._indirect(p)
        n = struct.unpack_from("<I", self.buf, start)[0]
        return self.buf[start + 4:start + 4 + n].decode("utf-8", errors="replace")

    def vector(self, slot: int, dtype) -> np.ndarray:
        """A vector of scalars, as a numpy array (a copy)."""
        p = self._field(slot)
        if not p:
            return np.zeros(0, dtype)
        start = self._indirect(p)
        n = struct.unpack_from("<I", self.buf, start)[0]
        dtype = np.dtype(dtype).newbyteorder("<")
        end = start + 4 + n * dtype.itemsize
        if end > len(self.buf):
            raise TfliteFormatError("vector runs past the end of the file")
        return np.frombuffer(self.buf, dtype, n, start + 4).copy()

    def tables(self, slot: int) -> list[_Table]:
        """A vector of tables."""
        p = self._field(slot)
        if not p:
            return []
        start = self._indirect(p)
        n = struct.unpack_from("<I", self.buf, start)[0]
        return [_Table(self.buf, self._indirect(start + 4 + 4 * i)) for i in range(n)]


def _operator_name(code: _Table) -> tuple[str, bool]:
    # OperatorCode: deprecated_builtin_code:byte (slot 0), custom_code:string (1),
    # version:int (2), builtin_code:int (3). The real code is the larger of the two.
    builtin = max(code.scalar(0, "b", 0), code.scalar(3, "i", 0))
    if builtin == 32:  # CUSTOM
        return code.string(1) or "CUSTOM", True
    if builtin < len(BUILTIN_OPERATORS):
        return BUILTIN_OPERATORS[builtin], False
    return LATER_OPERATORS.get(builtin, f"BUILTIN_{builtin}"), False


def _options(name: str, op: _Table) -> dict:
    fields = _OPTION_FIELDS.get(name)
    table = op.table(4)  # builtin_options (slot 3 is the union's type byte)
    if not fields:
        return {}
    out = {}
    for slot, (key, fmt, default) in enumerate(fields):
        if table is None:
            out[key] = default
        elif fmt.startswith("["):
            out[key] = [int(v) for v in table.vector(slot, np.int32)]
        else:
            out[key] = table.scalar(slot, fmt, default)
    return out


def read_tflite(data: bytes) -> TfliteGraph:
    """Parse a .tflite file's bytes into its first subgraph.

    Constant tensors get their data as numpy arrays of the tensor's dtype and shape;
    raises :class:`TfliteFormatError` for bytes that are not a TFLite model.
    """
    buf = bytes(data)
    if len(buf) < 8 or buf[4:8] != b"TFL3":
        raise TfliteFormatError("not a TFLite model (no 'TFL3' file identifier)")
    model = _Table(buf, struct.unpack_from("<I", buf, 0)[0])
    # Model: version (0), operator_codes (1), subgraphs (2), description (3), buffers (4).
    version = model.scalar(0, "I", 0)
    codes = [_operator_name(c) for c in model.tables(1)]
    subgraphs = model.tables(2)
    if not subgraphs:
        raise TfliteFormatError("TFLite model has no subgraph")
    buffers = model.tables(4)

    def buffer_bytes(index: int) -> bytes | None:
        if index <= 0 or index >= len(buffers):
            return None  # buffer 0 is the empty sentinel
        b = buffers[index]
        content = b.vector(0, np.uint8)  # Buffer.data
        if content.size:
            return content.tobytes()
        offset, size = b.scalar(1, "Q", 0), b.scalar(2, "Q", 0)  # large models keep data after the flatbuffer
        if offset > 1 and size:
            return buf[offset:offset + size]
        return None

    graph = subgraphs[0]
    tensors = []
    # SubGraph: tensors (0), inputs (1), outputs (2), operators (3), name (4).
    for i, t in enumerate(graph.tables(0)):
        # Tensor: shape (0), type (1), buffer (2), name (3), quantization (4).
        shape = tuple(int(v) for v in t.vector(0, np.int32))
        type_code = t.scalar(1, "b", 0)
        if type_code not in TENSOR_TYPES:
            dtype = np.dtype(np.uint8)  # unsupported type; operators using it will be rejected
        else:
            dtype = TENSOR_TYPES[type_code]
        raw = buffer_bytes(t.scalar(2, "I", 0))
        arr = None
        if raw is not None:
            count = int(np.prod(shape)) if shape else 1
            if len(raw) != count * dtype.itemsize:
                raise TfliteFormatError(f"tensor {t.string(3)!r}: {len(raw)} bytes for shape {shape}")
            arr = np.frombuffer(raw, dtype.newbyteorder("<")).astype(dtype).reshape(shape)
        tensors.append(Tensor(i, t.string(3), shape, dtype, arr))
    operators = []
    for op in graph.tables(3):
        # Operator: opcode_index (0), inputs (1), outputs (2), options type (3), options (4),
        # custom options (5).
        index = op.scalar(0, "I", 0)
        if index >= len(codes):
            raise TfliteFormatError(f"operator code index {index} out of range")
        name, custom = codes[index]
        operators.append(Operator(
            name=name,
            inputs=[int(v) for v in op.vector(1, np.int32)],
            outputs=[int(v) for v in op.vector(2, np.int32)],
            options={} if custom else _options(name, op),
            custom=custom,
            custom_options=op.vector(5, np.uint8).tobytes() if custom else b"",
        ))
    return TfliteGraph(
        tensors=tensors,
        operators=operators,
        inputs=[int(v) for v in graph.vector(1, np.int32)],
        outputs=[int(v) for v in graph.vector(2, np.int32)],
        version=version,
        description=model.string(3),
    )
