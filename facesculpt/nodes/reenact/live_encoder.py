"""Model-based coding of a live face: the parts of a `.fsc` stream made frame by frame.

A file's encoder sees the whole video before it chooses its expression basis; a live one cannot.
:class:`LiveEncoder` learns the basis from the first ``learn_frames`` frames with a face, then sends
its key (the frame that completes the learning: its image, fit and the neutral;
:func:`facesculpt.coding.fsc.pack_key_arrays`) and the basis (:func:`~facesculpt.coding.fsc.pack_basis`),
and from then on one record per frame: the face's pose as a similarity (7 numbers) and its
expression displacement from the key's neutral projected onto the basis. An expression the learning
frames never showed is carried only as far as the basis spans it: a frame the basis misses by more
than ``refresh_mm`` (RMS over the vertices) is kept, and after ``refresh_frames`` such frames the
basis is learnt again from the frames kept (the first ones and the missed ones, at most
:data:`POOL_FRAMES`) and sent again; the keyframe stays. The coefficient steps leave
:data:`STEP_HEADROOM` times the learnt range before they clip.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesculpt.coding.fsc import (
    FORMAT_VERSION,
    KEY_QUALITY,
    coefficient_steps,
    keyframe_image,
    pack_basis,
    pack_key_arrays,
    pack_records,
)
from facesculpt.geometry.similarity import similarity_vector

from .expression_basis import expression_basis, expression_coefficients

#: Coefficient range kept beyond the largest one seen while learning (int8 steps are widened by it).
STEP_HEADROOM = 1.5
#: Frames a basis is learnt from, at most (the first ones, then the ones a basis missed).
POOL_FRAMES = 300


@dataclass
class CodedKeyParts:
    """A keyframe as ``coding/key`` carries it: header (dict: fps, width, height, K, vertices,
    model, version), keyframe (WebP bytes), arrays (:func:`~facesculpt.coding.fsc.pack_key_arrays`)."""

    header: dict
    keyframe: bytes
    arrays: bytes


@dataclass
class CodedBasisParts:
    """A basis as ``coding/basis`` carries it: version (1, 2, ...), arrays
    (:func:`~facesculpt.coding.fsc.pack_basis`), basis_steps (C,), coeff_steps (C,), record (the
    keyframe's own record in this basis)."""

    version: int
    arrays: bytes
    basis_steps: np.ndarray
    coeff_steps: np.ndarray
    record: bytes


class LiveEncoder:
    """Frame-by-frame coder of one face (see the module docstring).

    triangles: (T, 3) the model's mesh (the basis is sent at control vertices of it);
    components: expression coefficients per frame (1..64); learn_frames: frames with a face the
    first basis is learnt from; key_quality: the keyframe's WebP quality; fps: the rate written in the header;
    refresh_mm: a frame the basis misses by more (RMS, mm) counts toward a new basis (0: never);
    refresh_frames: how many such frames call for it."""

    def __init__(self, triangles: np.ndarray, components: int = 12, learn_frames: int = 90,
                 key_quality: int = KEY_QUALITY, fps: float = 30.0, model_id: str = "facemesh",
                 refresh_mm: float = 1.0, refresh_frames: int = 15):
        self.triangles = np.asarray(triangles)
        self.components, self.learn_frames = int(components), int(learn_frames)
        self.key_quality, self.fps, self.model_id = int(key_quality), float(fps), model_id
        self.refresh_mm, self.refresh_frames = float(refresh_mm), int(refresh_frames)
        self.pool: list[np.ndarray] = []
        self.missed = 0
        self.bases = 0
        self.key: CodedKeyParts | None = None
        self.keyframe: tuple | None = None  # the keyframe's (shape, camera vertices)
        self.neutral = self.mean = self.basis = self.steps = None

    @property
    def learning(self) -> bool:
        return self.key is None

    def add(self, shape: np.ndarray, camera_vertices: np.ndarray, projected: np.ndarray, image: np.ndarray | None,
            K: np.ndarray | None, neutral: np.ndarray
            ) -> tuple[CodedKeyParts | None, CodedBasisParts | None, bytes | None]:
        """Code one frame with a face: shape (V, 3) model mm (its fitted shape), camera_vertices (V,
        3) and projected (V, 2) px (its fit in the frame), image (H, W, 3) uint8 BGR (the frame; may
        be None while it is not at hand, then the first key waits for a frame that has it), K (3, 3)
        or None, neutral (V, 3) mm (the person's, as learnt now; the key fixes it). Returns (the key
        when it is made, a new basis when one is learnt, this frame's record in the newest basis or
        None while learning)."""
        shape = np.asarray(shape, np.float64)
        if self.key is None:
            self.pool.append(shape.astype(np.float32))
            if len(self.pool) < self.learn_frames or image is None:
                return None, None, None
            self.neutral = np.asarray(neutral, np.float64)
            self.keyframe = (shape, np.asarray(camera_vertices, np.float32))
            self.key = CodedKeyParts(
                {"version": FORMAT_VERSION, "model": self.model_id, "fps": self.fps, "width": int(image.shape[1]),
                 "height": int(image.shape[0]), "vertices": int(len(self.neutral)),
                 "K": None if K is None else np.asarray(K).tolist()},
                keyframe_image(image, self.key_quality),
                pack_key_arrays(camera_vertices, self.neutral, None if K is not None else projected))
            self.pool = self.pool[-POOL_FRAMES:]
            basis = self._learn_basis()
            return self.key, basis, basis.record
        record, miss = self._record(shape, camera_vertices)
        if self.refresh_mm > 0 and miss > self.refresh_mm:
            self.pool = (self.pool + [shape.astype(np.float32)])[-POOL_FRAMES:]
            self.missed += 1
            if self.missed >= self.refresh_frames:
                basis = self._learn_basis()
                return None, basis, self._record(shape, camera_vertices)[0]
        return None, None, record

    def _record(self, shape: np.ndarray, camera_vertices: np.ndarray) -> tuple[bytes, float]:
        """A frame's record and how far the basis misses its expression (RMS over vertices, mm)."""
        pose = similarity_vector(shape, camera_vertices)
        displacement = shape - self.neutral
        coeffs = expression_coefficients(displacement, self.mean, self.basis)
        miss = displacement.ravel() - self.mean - coeffs[0] @ self.basis
        return pack_records([True], pose[None], coeffs, self.steps), float(np.sqrt((miss ** 2).sum() / len(shape)))

    def empty_record(self) -> bytes | None:
        """The record of a frame without a face (the decoder holds the last face); None before the key."""
        if self.key is None:
            return None
        return pack_records([False], np.zeros((1, 7)), np.zeros((1, len(self.steps))), self.steps)

    def _learn_basis(self) -> CodedBasisParts:
        """A basis of the frames kept, and the keyframe's record in it."""
        E = np.stack(self.pool).astype(np.float64) - self.neutral
        self.mean, self.basis = expression_basis(E, self.components)
        self.steps = coefficient_steps(expression_coefficients(E, self.mean, self.basis)) * STEP_HEADROOM
        self.missed = 0
        self.bases += 1
        blob, basis_steps = pack_basis(self.mean, self.basis, self.triangles, self.neutral)
        return CodedBasisParts(self.bases, blob, basis_steps, self.steps.copy(), self._record(*self.keyframe)[0])
