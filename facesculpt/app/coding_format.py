"""The `.fsc` stream of model-based coding: one header, then a fixed-size record per frame.

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
#: Arrays of the header: name -> stored dtype.
ARRAYS = {"key_vertices": "<f4", "key_projected": "<f4", "neutral": "<f2", "mean": "<f2", "basis": "i1"}


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


def write_stream(path, header: dict, keyframe_jpeg: bytes, arrays: dict, present: np.ndarray,
                 pose: np.ndarray, coeffs: np.ndarray) -> dict:
    """Write a `.fsc` file; pose (F, 7) float, coeffs (F, C) float (quantised here with the
    header's ``coeff_steps``; the basis rows to int8, each with its own step, ``basis_steps`` added
    to the header). Returns the byte counts of its parts (header, keyframe, arrays,
    records, total)."""
    basis = np.asarray(arrays["basis"], np.float64)
    header = dict(header, basis_steps=np.maximum(np.abs(basis).max(axis=1, initial=0.0) / 127.0, 1e-9).tolist())
    arrays = dict(arrays, basis=np.round(basis / np.asarray(header["basis_steps"])[:, None]))
    steps = np.asarray(header["coeff_steps"], np.float64)
    qc = np.clip(np.round(np.asarray(coeffs, np.float64) / steps), -127, 127).astype(np.int8)
    qp = quantise_pose(pose)
    head = json.dumps(header).encode()
    blob = zlib.compress(b"".join(np.ascontiguousarray(arrays[k], ARRAYS[k]).tobytes() for k in ARRAYS), 9)
    records = b"".join(struct.pack("<B", int(p)) + qp[i].astype("<i2").tobytes() + qc[i].tobytes()
                       for i, p in enumerate(present))
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
    header = json.loads(parts[0])
    raw = zlib.decompress(parts[2])
    V, C = int(header["vertices"]), int(header["components"])
    shapes = {"key_vertices": (V, 3), "key_projected": (V, 2), "neutral": (V, 3), "mean": (3 * V,),
              "basis": (C, 3 * V)}
    arrays, off = {}, 0
    for name, dtype in ARRAYS.items():
        count = int(np.prod(shapes[name]))
        arrays[name] = np.frombuffer(raw, dtype, count, off).reshape(shapes[name]).astype(np.float32)
        off += count * np.dtype(dtype).itemsize
    arrays["basis"] *= np.asarray(header["basis_steps"], np.float32)[:, None]
    size = record_bytes(C)
    frames = (len(data) - pos) // size
    if frames != int(header["frames"]):
        raise ValueError(f"{path} holds {frames} frame records, its header says {header['frames']}")
    rec = np.frombuffer(data, np.uint8, frames * size, pos).reshape(frames, size)
    present = rec[:, 0].astype(bool)
    qp = rec[:, 1:15].copy().view("<i2")
    qc = rec[:, 15:].copy().view(np.int8)
    sizes = {"header": 8 + len(parts[0]), "keyframe": 4 + len(parts[1]), "arrays": 4 + len(parts[2]),
             "records": frames * size, "total": len(data)}
    return CodedStream(header, parts[1], arrays, present, dequantise_pose(qp),
                       qc.astype(np.float64) * np.asarray(header["coeff_steps"], np.float64), sizes)
