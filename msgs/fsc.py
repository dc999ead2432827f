"""The `.fsc` stream of model-based coding: one header, then a fixed-size record per frame.

The same parts travel on the graph, split where a live coder changes them at different times:
``coding/key`` (:class:`~facesculpt.msgs.types.CodedKey`) carries the header JSON, the keyframe
JPEG and the keyframe's arrays (:data:`KEY_ARRAYS`, :func:`pack_key_arrays`), ``coding/basis``
(:class:`~facesculpt.msgs.types.CodedBasis`) the expression basis (:data:`BASIS_ARRAYS`,
:func:`pack_basis`), learnt again now and then, and ``coding/frame``
(:class:`~facesculpt.msgs.types.CodedFrame`) one record, byte for byte as a file holds it.

Layout (little-endian)::

    b"FSC1"  u32 n  header JSON (n bytes, UTF-8)
    u32 n  keyframe JPEG (n bytes)           the first coded frame, whole: face texture and background
    u32 n  zlib(arrays)                      key fit (float32), neutral, mean (float16), basis (int8)
    records, RECORD_BYTES(components) each   one per frame, in order

A record is the per-frame stream: a flag byte (1: a face; 0: none, the decoder holds the last
parameters), the pose as 7 int16 (rotation vector in :data:`ROT_STEP` rad, translation in
:data:`TRANS_STEP` mm, log scale in :data:`LOG_SCALE_STEP`), then the expression as ``components``
int8 coefficients of the header's basis, each with its own step (``coeff_steps``). The header and
the keyframe are sent once; what a live link spends per second is ``RECORD_BYTES * fps``.
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

MAGIC = b"FSC1"
#: Quantisation steps of the pose: rad, mm (camera space), natural log of the scale.
ROT_STEP = 1e-4
TRANS_STEP = 0.1
LOG_SCALE_STEP = 1e-4
#: Arrays of the header: name -> stored dtype; the keyframe's, then the expression basis's.
KEY_ARRAYS = {"key_vertices": "<f4", "key_projected": "<f4", "neutral": "<f2"}
BASIS_ARRAYS = {"mean": "<f2", "basis": "i1"}
ARRAYS = {**KEY_ARRAYS, **BASIS_ARRAYS}


def record_bytes(components: int) -> int:
    """Bytes of one frame's record with ``components`` expression coefficients."""
    return 1 + 7 * 2 + int(components)


@dataclass
class CodedStream:
    """A decoded `.fsc` file. header: fps, frames, width, height, K, model, components, coeff_steps;
    keyframe_jpeg: bytes; arrays: :data:`ARRAYS` as float32 (key_vertices (V, 3) camera space,
    key_projected (V, 2) px, neutral (V, 3) model mm, mean (3V,), basis (C, 3V) mm per unit, dequantised);
    present (F,) bool; pose (F, 7) float64 dequantised; coeffs (F, C) float64 dequantised."""

    header: dict
    keyframe_jpeg: bytes
    arrays: dict
    present: np.ndarray
    pose: np.ndarray
    coeffs: np.ndarray
    sizes: dict = field(default_factory=dict)


def quantise_pose(pose: np.ndarray) -> np.ndarray:
    """(F, 7) float pose (rotation vector rad, translation mm, log scale) -> (F, 7) int16."""
    steps = np.array([ROT_STEP] * 3 + [TRANS_STEP] * 3 + [LOG_SCALE_STEP])
    q = np.round(np.asarray(pose, np.float64) / steps)
    if np.abs(q).max(initial=0) > 32767:
        raise ValueError("a pose is out of the stream's range (rotation > 3.2 rad or translation > 3.2 m)")
    return q.astype(np.int16)


def dequantise_pose(q: np.ndarray) -> np.ndarray:
    steps = np.array([ROT_STEP] * 3 + [TRANS_STEP] * 3 + [LOG_SCALE_STEP])
    return np.asarray(q, np.float64) * steps


def coefficient_steps(coeffs: np.ndarray) -> np.ndarray:
    """(C,) the step of each coefficient so that its largest magnitude over (F, C) fits int8."""
    peak = np.abs(np.asarray(coeffs, np.float64)).max(axis=0, initial=0.0)
    return np.maximum(peak / 127.0, 1e-6)


def _shapes(V: int, C: int) -> dict:
    return {"key_vertices": (V, 3), "key_projected": (V, 2), "neutral": (V, 3), "mean": (3 * V,), "basis": (C, 3 * V)}


def basis_steps(basis: np.ndarray) -> np.ndarray:
    """(C,) float64 the step of each basis row (C, 3V) so that its largest magnitude fits int8."""
    return np.maximum(np.abs(np.asarray(basis, np.float64)).max(axis=1, initial=0.0) / 127.0, 1e-9)


def _array_bytes(arrays: dict, dtypes: dict, steps: np.ndarray | None = None) -> bytes:
    """The arrays named in ``dtypes``, stored as they say (``basis`` divided by its row ``steps``)."""
    out = []
    for name, dtype in dtypes.items():
        a = np.asarray(arrays[name], np.float64)
        if name == "basis":
            a = np.round(a / np.asarray(steps)[:, None])
        out.append(np.ascontiguousarray(a, dtype).tobytes())
    return b"".join(out)


def _arrays_from(raw: bytes, dtypes: dict, V: int, C: int, steps=None) -> dict:
    """float32 arrays of ``dtypes`` from :func:`_array_bytes`' bytes; ValueError on a size mismatch."""
    shapes = _shapes(V, C)
    need = sum(int(np.prod(shapes[k])) * np.dtype(d).itemsize for k, d in dtypes.items())
    if len(raw) != need:
        raise ValueError(f"a coded stream's arrays hold {len(raw)} bytes where {need} are needed")
    arrays, off = {}, 0
    for name, dtype in dtypes.items():
        count = int(np.prod(shapes[name]))
        arrays[name] = np.frombuffer(raw, dtype, count, off).reshape(shapes[name]).astype(np.float32)
        off += count * np.dtype(dtype).itemsize
    if "basis" in arrays:
        arrays["basis"] *= np.asarray(steps, np.float32)[:, None]
    return arrays


def _inflate(blob: bytes) -> bytes:
    try:
        return zlib.decompress(blob)
    except zlib.error as exc:
        raise ValueError(f"a coded stream's arrays are not zlib data: {exc}") from None


def pack_key_arrays(arrays: dict) -> bytes:
    """zlib of the keyframe's :data:`KEY_ARRAYS` (key_vertices (V, 3), key_projected (V, 2), neutral (V, 3))."""
    return zlib.compress(_array_bytes(arrays, KEY_ARRAYS), 9)


def unpack_key_arrays(blob: bytes, vertices: int) -> dict:
    """float32 :data:`KEY_ARRAYS` from :func:`pack_key_arrays`; ValueError when they do not fit."""
    return _arrays_from(_inflate(blob), KEY_ARRAYS, int(vertices), 0)


def pack_basis(mean: np.ndarray, basis: np.ndarray) -> tuple[bytes, np.ndarray]:
    """(zlib of :data:`BASIS_ARRAYS`, the basis rows' steps (C,)): mean (3V,) and basis (C, 3V) mm."""
    steps = basis_steps(basis)
    return zlib.compress(_array_bytes({"mean": mean, "basis": basis}, BASIS_ARRAYS, steps), 9), steps


def unpack_basis(blob: bytes, vertices: int, steps: np.ndarray) -> dict:
    """float32 mean (3V,) and basis (C, 3V) (dequantised with ``steps`` (C,)) from :func:`pack_basis`."""
    return _arrays_from(_inflate(blob), BASIS_ARRAYS, int(vertices), len(steps), steps)


def pack_header(header: dict, arrays: dict) -> tuple[dict, bytes, bytes]:
    """A file's once-sent parts: ``header`` with ``basis_steps`` added (the basis rows go to int8,
    each with its own step), its JSON bytes, and zlib of :data:`ARRAYS` (float arrays as the module
    docstring says; ``basis`` (C, 3V) float, quantised here)."""
    steps = basis_steps(arrays["basis"])
    header = dict(header, basis_steps=steps.tolist())
    blob = zlib.compress(_array_bytes(arrays, ARRAYS, steps), 9)
    return header, json.dumps(header).encode(), blob


def unpack_header(head: bytes, blob: bytes) -> tuple[dict, dict]:
    """(header dict, arrays as float32, dequantised) from :func:`pack_header`'s JSON and blob;
    ValueError when they do not fit together."""
    try:
        header = json.loads(head)
        V, C, steps = int(header["vertices"]), int(header["components"]), header["basis_steps"]
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"not a coded stream's header: {exc}") from None
    if len(steps) != C:
        raise ValueError(f"a coded stream's header has {len(steps)} basis steps for {C} components")
    return header, _arrays_from(_inflate(blob), ARRAYS, V, C, steps)


def pack_records(present: np.ndarray, pose: np.ndarray, coeffs: np.ndarray, coeff_steps: np.ndarray) -> bytes:
    """The per-frame records of present (F,) bool, pose (F, 7) float and coeffs (F, C) float
    (quantised with ``coeff_steps`` (C,), clipped to int8), concatenated."""
    steps = np.asarray(coeff_steps, np.float64)
    qc = np.clip(np.round(np.atleast_2d(np.asarray(coeffs, np.float64)) / steps), -127, 127).astype(np.int8)
    qp = quantise_pose(np.atleast_2d(pose))
    return b"".join(struct.pack("<B", int(p)) + qp[i].astype("<i2").tobytes() + qc[i].tobytes()
                    for i, p in enumerate(np.atleast_1d(present)))


def unpack_records(data: bytes, coeff_steps: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """present (F,) bool, pose (F, 7) float64 and coeffs (F, C) float64 (dequantised) of whole
    records ``data`` with C = len(coeff_steps); ValueError when its length is not a whole number
    of records."""
    steps = np.asarray(coeff_steps, np.float64)
    size = record_bytes(len(steps))
    if len(data) % size:
        raise ValueError(f"{len(data)} bytes are not whole records of {size} bytes")
    rec = np.frombuffer(data, np.uint8).reshape(-1, size)
    qp = rec[:, 1:15].copy().view("<i2")
    qc = rec[:, 15:].copy().view(np.int8)
    return rec[:, 0].astype(bool), dequantise_pose(qp), qc.astype(np.float64) * steps


def write_stream(path, header: dict, keyframe_jpeg: bytes, arrays: dict, present: np.ndarray,
                 pose: np.ndarray, coeffs: np.ndarray) -> dict:
    """Write a `.fsc` file; pose (F, 7) float, coeffs (F, C) float (quantised here with the
    header's ``coeff_steps``; the basis as :func:`pack_header` says). Returns the byte counts of
    its parts (header, keyframe, arrays, records, total)."""
    header, head, blob = pack_header(header, arrays)
    records = pack_records(present, pose, coeffs, header["coeff_steps"])
    with open(path, "wb") as f:
        for part in (head, keyframe_jpeg, blob):
            f.write((MAGIC if part is head else b"") + struct.pack("<I", len(part)) + part)
        f.write(records)
    sizes = {"header": 8 + len(head), "keyframe": 4 + len(keyframe_jpeg), "arrays": 4 + len(blob),
             "records": len(records)}
    sizes["total"] = sum(sizes.values())
    return sizes


def read_stream(path) -> CodedStream:
    """Read a `.fsc` file; ValueError in one sentence when it is not one or is cut short."""
    data = open(path, "rb").read()
    if data[:4] != MAGIC:
        raise ValueError(f"{path} is not a facesculpt coded stream (.fsc)")
    pos, parts = 4, []
    for _ in range(3):
        if pos + 4 > len(data):
            raise ValueError(f"{path} is cut short in its header")
        (n,) = struct.unpack_from("<I", data, pos)
        parts.append(data[pos + 4:pos + 4 + n])
        pos += 4 + n
    header, arrays = unpack_header(parts[0], parts[2])
    size = record_bytes(int(header["components"]))
    frames = (len(data) - pos) // size
    if frames != int(header["frames"]):
        raise ValueError(f"{path} holds {frames} frame records, its header says {header['frames']}")
    present, pose, coeffs = unpack_records(data[pos:pos + frames * size], header["coeff_steps"])
    sizes = {"header": 8 + len(parts[0]), "keyframe": 4 + len(parts[1]), "arrays": 4 + len(parts[2]),
             "records": frames * size, "total": len(data)}
    return CodedStream(header, parts[1], arrays, present, pose, coeffs, sizes)
