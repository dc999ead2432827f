"""The `.fsc` stream of model-based coding: one header, then a fixed-size record per frame.

The same parts travel on the graph, split where a live coder changes them at different times:
``coding/key`` (:class:`~facesculpt.msgs.types.CodedKey`) carries the header JSON, the keyframe
image and the keyframe's arrays (:func:`pack_key_arrays`), ``coding/basis``
(:class:`~facesculpt.msgs.types.CodedBasis`) the expression basis (:func:`pack_basis`), learnt
again now and then, and ``coding/frame`` (:class:`~facesculpt.msgs.types.CodedFrame`) one record,
byte for byte as a file holds it.

Layout (little-endian; format version 2, the header's ``version``)::

    b"FSC1"  u32 n  header JSON (n bytes, UTF-8)
    u32 n  keyframe image (n bytes, WebP)    the first coded frame, whole: face texture and background
    u32 n  key arrays (:func:`pack_key_arrays`)   the keyframe's fit and the person's neutral
    u32 n  basis (:func:`pack_basis`)             the expression basis at control vertices
    records, RECORD_BYTES(components) each   one per frame, in order

The once-sent parts are small because they are quantised where it does not show: the keyframe's
mesh and the neutral as int16 in :data:`KEY_STEP` mm, its pixels not at all when the header has K
(they are its projection), and the expression basis at :data:`CONTROL_POINTS` control vertices
only, int8, filled in over the mesh by biharmonic interpolation
(:mod:`facesculpt.geometry.biharmonic`) by the receiver, who has the mesh. Format version 1 (every
array whole, in one part; keyframe JPEG) is still read.

A record is the per-frame stream: a flag byte (1: a face; 0: none, the decoder holds the last
parameters), the pose as 7 int16 (rotation vector in :data:`ROT_STEP` rad, translation in
:data:`TRANS_STEP` mm, log scale in :data:`LOG_SCALE_STEP`), then the expression as ``components``
int8 coefficients of the basis, each with its own step (``coeff_steps``). The header and the
keyframe are sent once; what a live link spends per second is ``RECORD_BYTES * fps``.
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from facesculpt.geometry.biharmonic import biharmonic_interpolation, control_values, farthest_point_samples
from facesculpt.geometry.projection import project

MAGIC = b"FSC1"
FORMAT_VERSION = 2
#: Quantisation steps of the pose: rad, mm (camera space), natural log of the scale.
ROT_STEP = 1e-4
TRANS_STEP = 0.1
LOG_SCALE_STEP = 1e-4
#: The keyframe's mesh (about its centroid) and the neutral: int16 in this step, mm.
KEY_STEP = 0.02
#: Control vertices the expression basis is sent at (all of them for smaller meshes).
CONTROL_POINTS = 100
#: WebP quality of the keyframe image (the face's texture: its PSNR hardly moves from 60 to 80).
KEY_QUALITY = 70
#: Format version 1's arrays, in one part: name -> stored dtype.
V1_ARRAYS = {"key_vertices": "<f4", "key_projected": "<f4", "neutral": "<f2", "mean": "<f2", "basis": "i1"}


def record_bytes(components: int) -> int:
    """Bytes of one frame's record with ``components`` expression coefficients."""
    return 1 + 7 * 2 + int(components)


@dataclass
class CodedStream:
    """A decoded `.fsc` file. header: fps, frames, width, height, K, model, components, coeff_steps;
    keyframe: the keyframe image's bytes (WebP, or JPEG in version 1); arrays: float32
    key_vertices (V, 3) camera space, key_projected (V, 2) px, neutral (V, 3) model mm, mean
    (3V,), basis (C, 3V) mm per unit, dequantised; present (F,) bool; pose (F, 7) float64
    dequantised; coeffs (F, C) float64 dequantised."""

    header: dict
    keyframe: bytes
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


def keyframe_image(image: np.ndarray, quality: int = KEY_QUALITY) -> bytes:
    """(H, W, 3) uint8 BGR -> the keyframe's WebP bytes at ``quality`` (1..100)."""
    import cv2

    ok, data = cv2.imencode(".webp", image, [cv2.IMWRITE_WEBP_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("cannot encode the keyframe as WebP")
    return data.tobytes()


def _inflate(blob: bytes) -> bytes:
    try:
        return zlib.decompress(blob)
    except zlib.error as exc:
        raise ValueError(f"a coded stream's arrays are not zlib data: {exc}") from None


def _int16(values: np.ndarray, step: float, what: str) -> bytes:
    q = np.round(np.asarray(values, np.float64) / step)
    if np.abs(q).max(initial=0) > 32767:
        raise ValueError(f"the {what} is out of the stream's range ({32767 * step:g} mm)")
    return q.astype("<i2").tobytes()


def pack_key_arrays(key_vertices: np.ndarray, neutral: np.ndarray, key_projected: np.ndarray | None = None) -> bytes:
    """zlib of the keyframe's fit and the neutral: centroid (3,) float32 of ``key_vertices`` (V, 3)
    camera space, the vertices about it and ``neutral`` (V, 3) model mm as int16 in
    :data:`KEY_STEP`, then ``key_projected`` (V, 2) px float32 only when given (a stream without
    K; with K the receiver projects the vertices)."""
    kv = np.asarray(key_vertices, np.float64)
    centroid = kv.mean(axis=0).astype(np.float32)
    parts = [centroid.astype("<f4").tobytes(), _int16(kv - centroid, KEY_STEP, "keyframe's mesh"),
             _int16(neutral, KEY_STEP, "neutral")]
    if key_projected is not None:
        parts.append(np.ascontiguousarray(key_projected, "<f4").tobytes())
    return zlib.compress(b"".join(parts), 9)


def unpack_key_arrays(blob: bytes, vertices: int, K: np.ndarray | None = None) -> dict:
    """float32 key_vertices (V, 3), key_projected (V, 2) (projected with ``K`` (3, 3) when the
    blob does not hold them) and neutral (V, 3) from :func:`pack_key_arrays`; ValueError when
    they do not fit."""
    raw, V = _inflate(blob), int(vertices)
    base = 12 + 2 * 6 * V
    if len(raw) not in (base, base + 8 * V) or (len(raw) == base and K is None):
        raise ValueError(f"a coded stream's key arrays hold {len(raw)} bytes, not those of {V} vertices"
                         + ("" if K is not None else " with their pixels"))
    centroid = np.frombuffer(raw, "<f4", 3).astype(np.float64)
    q = np.frombuffer(raw, "<i2", 6 * V, 12).astype(np.float64) * KEY_STEP
    key_vertices = q[:3 * V].reshape(V, 3) + centroid
    if len(raw) > base:
        projected = np.frombuffer(raw, "<f4", 2 * V, base).reshape(V, 2).astype(np.float64)
    else:
        projected = project(key_vertices, np.asarray(K, np.float64))
    return {"key_vertices": key_vertices.astype(np.float32), "key_projected": projected.astype(np.float32),
            "neutral": q[3 * V:].reshape(V, 3).astype(np.float32)}


def pack_basis(mean: np.ndarray, basis: np.ndarray, triangles: np.ndarray, points: np.ndarray,
               controls: int = CONTROL_POINTS) -> tuple[bytes, np.ndarray]:
    """(zlib of the expression basis at control vertices, the rows' steps (C,)): mean (3V,) and
    basis (C, 3V) mm, on the mesh of ``triangles`` (T, 3); the controls are ``controls`` vertices
    spread over ``points`` (V, 3) (the neutral), their values those whose biharmonic
    interpolation comes closest to each row. Layout: u16 m, the m control ids (int16), the mean's
    step (float32), the mean (m, 3) and the basis (C, m, 3) as int8."""
    points = np.asarray(points, np.float64)
    V = len(points)
    ids = farthest_point_samples(points, controls)
    H = biharmonic_interpolation(triangles, V, ids)
    B = np.asarray(basis, np.float64).reshape(-1, V, 3)
    mean_c = control_values(H, np.asarray(mean, np.float64).reshape(V, 3))
    basis_c = control_values(H, B.transpose(1, 0, 2)).transpose(1, 0, 2)  # (C, m, 3)
    mean_step = max(float(np.abs(mean_c).max(initial=0.0)) / 127.0, 1e-9)
    steps = np.maximum(np.abs(basis_c).reshape(len(B), -1).max(axis=1, initial=0.0) / 127.0, 1e-9)
    raw = b"".join([struct.pack("<H", len(ids)), ids.astype("<i2").tobytes(), struct.pack("<f", mean_step),
                    np.round(mean_c / mean_step).astype(np.int8).tobytes(),
                    np.round(basis_c / steps[:, None, None]).astype(np.int8).tobytes()])
    return zlib.compress(raw, 9), steps


def unpack_basis(blob: bytes, vertices: int, steps: np.ndarray, triangles: np.ndarray) -> dict:
    """float32 mean (3V,) and basis (C, 3V) (its rows dequantised with ``steps`` (C,)) from
    :func:`pack_basis`, interpolated over the mesh of ``triangles``; ValueError when they do not fit."""
    raw, V, C = _inflate(blob), int(vertices), len(steps)
    m = struct.unpack_from("<H", raw)[0] if len(raw) >= 2 else -1
    if m <= 0 or len(raw) != 2 + 2 * m + 4 + 3 * m * (1 + C):
        raise ValueError(f"a coded stream's basis holds {len(raw)} bytes, not {C} rows at {m} controls")
    ids = np.frombuffer(raw, "<i2", m, 2).astype(np.int64)
    (mean_step,) = struct.unpack_from("<f", raw, 2 + 2 * m)
    q = np.frombuffer(raw, np.int8, 3 * m * (1 + C), 6 + 2 * m).astype(np.float64)
    H = biharmonic_interpolation(triangles, V, ids)  # ValueError on ids outside the mesh
    mean = H @ (q[:3 * m].reshape(m, 3) * mean_step)
    basis = np.einsum("vm,cmk->cvk", H, q[3 * m:].reshape(C, m, 3) * np.asarray(steps, np.float64)[:, None, None])
    return {"mean": mean.reshape(-1).astype(np.float32), "basis": basis.reshape(C, -1).astype(np.float32)}


def unpack_header(head: bytes) -> dict:
    """The header dict of a stream's JSON; ValueError when it is not one."""
    try:
        header = json.loads(head)
        int(header["vertices"]), int(header["components"]), list(header["coeff_steps"])
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"not a coded stream's header: {exc}") from None
    if len(header["coeff_steps"]) != int(header["components"]):
        raise ValueError(f"a coded stream's header has {len(header['coeff_steps'])} coefficient steps for "
                         f"{header['components']} components")
    return header


def _v1_arrays(header: dict, blob: bytes) -> dict:
    """Format version 1's arrays (one zlib part, :data:`V1_ARRAYS`) as float32, dequantised."""
    V, steps = int(header["vertices"]), np.asarray(header.get("basis_steps", []), np.float32)
    shapes = {"key_vertices": (V, 3), "key_projected": (V, 2), "neutral": (V, 3), "mean": (3 * V,),
              "basis": (len(steps), 3 * V)}
    raw = _inflate(blob)
    if len(raw) != sum(int(np.prod(shapes[k])) * np.dtype(d).itemsize for k, d in V1_ARRAYS.items()):
        raise ValueError(f"a coded stream's arrays hold {len(raw)} bytes, not those its header says")
    arrays, off = {}, 0
    for name, dtype in V1_ARRAYS.items():
        count = int(np.prod(shapes[name]))
        arrays[name] = np.frombuffer(raw, dtype, count, off).reshape(shapes[name]).astype(np.float32)
        off += count * np.dtype(dtype).itemsize
    arrays["basis"] *= steps[:, None]
    return arrays


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
    flags, qp, qc = _record_fields(data, len(steps))
    return flags.astype(bool), dequantise_pose(qp), qc.astype(np.float64) * steps


def _record_fields(data: bytes, components: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whole records ``data`` -> (flags (F,) uint8, pose (F, 7) int16, coefficients (F, C) int8);
    ValueError when its length is not a whole number of records."""
    size = record_bytes(components)
    if len(data) % size:
        raise ValueError(f"{len(data)} bytes are not whole records of {size} bytes")
    rec = np.frombuffer(data, np.uint8).reshape(-1, size)
    return rec[:, 0], rec[:, 1:15].copy().view("<i2"), rec[:, 15:].copy().view(np.int8)


def _zigzag_planes(values: np.ndarray, nbytes: int) -> bytes:
    """Signed ints (any shape) -> their zigzag codes' bytes, least significant plane first."""
    v = np.asarray(values, np.int64).ravel()
    z = ((v << 1) ^ (v >> 63)).astype(np.uint64)
    return b"".join(((z >> (8 * b)) & 0xFF).astype(np.uint8).tobytes() for b in range(nbytes))


def _from_zigzag_planes(raw: bytes, count: int, nbytes: int) -> np.ndarray:
    planes = np.frombuffer(raw, np.uint8, count * nbytes).reshape(nbytes, count).astype(np.int64)
    z = sum(planes[b] << (8 * b) for b in range(nbytes))
    return (z >> 1) ^ -(z & 1)


def pack_record_block(records: bytes, components: int) -> bytes:
    """A file's records, smaller: each pose and coefficient column as its change from the frame
    before (they move slowly), zigzag-coded in byte planes, then zlib. :func:`unpack_record_block`
    gives back the very same bytes."""
    flags, pose, coeffs = _record_fields(records, components)
    dp = np.diff(pose.astype(np.int64), axis=0, prepend=np.zeros((1, 7), np.int64)).T
    dc = np.diff(coeffs.astype(np.int64), axis=0, prepend=np.zeros((1, int(components)), np.int64)).T
    return zlib.compress(flags.tobytes() + _zigzag_planes(dp, 3) + _zigzag_planes(dc, 2), 9)


def unpack_record_block(blob: bytes, components: int, frames: int) -> bytes:
    """The records :func:`pack_record_block` packed (``frames`` of them); ValueError when the
    block does not hold that many."""
    raw, F, C = _inflate(blob), int(frames), int(components)
    if len(raw) != F * (1 + 7 * 3 + C * 2):
        raise ValueError(f"a coded stream's records hold {len(raw)} bytes, not {F} frames of {C} coefficients")
    pose = np.cumsum(_from_zigzag_planes(raw[F:], 7 * F, 3).reshape(7, F).T, axis=0)
    coeffs = np.cumsum(_from_zigzag_planes(raw[F + 21 * F:], C * F, 2).reshape(C, F).T, axis=0)
    R = np.empty((F, record_bytes(C)), np.uint8)
    R[:, 0] = np.frombuffer(raw, np.uint8, F)
    R[:, 1:15] = np.ascontiguousarray(pose.astype("<i2")).view(np.uint8).reshape(F, 14)
    R[:, 15:] = np.ascontiguousarray(coeffs.astype(np.int8)).view(np.uint8).reshape(F, C)
    return R.tobytes()


def write_stream(path, header: dict, keyframe: bytes, key_arrays: bytes, basis: bytes, present: np.ndarray,
                 pose: np.ndarray, coeffs: np.ndarray) -> dict:
    """Write a `.fsc` file (format :data:`FORMAT_VERSION`): ``header`` (fps, frames, width, height,
    K, model, vertices, components, key, basis_steps, coeff_steps), the keyframe image's bytes,
    :func:`pack_key_arrays` and :func:`pack_basis` blobs, pose (F, 7) and coeffs (F, C) float
    (quantised here with the header's ``coeff_steps``). Returns the byte counts of its parts
    (header, keyframe, arrays, records, total)."""
    header = dict(header, version=FORMAT_VERSION)
    head = json.dumps(header).encode()
    unpack_header(head)
    records = pack_records(present, pose, coeffs, header["coeff_steps"])
    block = pack_record_block(records, int(header["components"]))
    with open(path, "wb") as f:
        f.write(MAGIC)
        for part in (head, keyframe, key_arrays, basis, block):
            f.write(struct.pack("<I", len(part)) + part)
    sizes = {"header": 8 + len(head), "keyframe": 4 + len(keyframe), "arrays": 8 + len(key_arrays) + len(basis),
             "records": 4 + len(block)}
    sizes["total"] = sum(sizes.values())
    sizes["stream"] = len(records)
    return sizes


def read_stream(path, triangles_of=None) -> CodedStream:
    """Read a `.fsc` file; ValueError in one sentence when it is not one or is cut short.
    ``triangles_of(model)``: the (T, 3) triangles of the header's model (format 2 interpolates
    its basis over them)."""
    data = open(path, "rb").read()
    if data[:4] != MAGIC:
        raise ValueError(f"{path} is not a facesculpt coded stream (.fsc)")
    pos, parts = 4, []

    def read_part() -> None:
        nonlocal pos
        if pos + 4 > len(data):
            raise ValueError(f"{path} is cut short in its header")
        (n,) = struct.unpack_from("<I", data, pos)
        parts.append(data[pos + 4:pos + 4 + n])
        pos += 4 + n

    read_part()
    header = unpack_header(parts[0])
    v1 = header.get("version", 1) == 1
    for _ in range(2 if v1 else 4):  # keyframe and arrays; format 2: key arrays, basis and records apart
        read_part()
    if v1:
        arrays = _v1_arrays(header, parts[2])
    else:
        if triangles_of is None:
            raise ValueError(f"{path}: its basis needs the triangles of the {header.get('model')} model")
        V = int(header["vertices"])
        arrays = unpack_key_arrays(parts[2], V, header.get("K"))
        arrays.update(unpack_basis(parts[3], V, header["basis_steps"], triangles_of(header["model"])))
    size, frames = record_bytes(int(header["components"])), int(header["frames"])
    if not v1:
        records = unpack_record_block(parts[4], int(header["components"]), frames)
    elif (len(data) - pos) // size == frames:
        records = data[pos:pos + frames * size]
    else:
        raise ValueError(f"{path} holds {(len(data) - pos) // size} frame records, its header says {frames}")
    present, pose, coeffs = unpack_records(records, header["coeff_steps"])
    sizes = {"header": 8 + len(parts[0]), "keyframe": 4 + len(parts[1]),
             "arrays": sum(4 + len(b) for b in parts[2:4]), "records": len(data) - pos + sum(4 + len(b) for b in parts[4:]),
             "total": len(data), "stream": len(records)}
    return CodedStream(header, parts[1], arrays, present, pose, coeffs, sizes)
