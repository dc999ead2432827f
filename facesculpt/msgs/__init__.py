"""Message types: the contract between nodes (docs/architecture.md "Topics")."""

from .codec import REGISTRY, DecodeError, Message, decode, encode, summarize
from .types import (
    INPUT_COMMANDS,
    INPUT_KINDS,
    CodedBasis,
    CodedFrame,
    CodedKey,
    Deformation,
    Diagnostics,
    FaceExpression,
    FaceLandmarks,
    FaceModel,
    FaceState,
    FaceTexture,
    FrameDone,
    HandLandmarks,
    Image,
    InputEvent,
)

__all__ = [
    "REGISTRY", "DecodeError", "Message", "decode", "encode", "summarize",
    "Image", "FaceExpression", "FaceLandmarks", "FaceModel", "FaceState", "InputEvent", "Deformation", "Diagnostics", "FrameDone",
    "HandLandmarks", "FaceTexture", "CodedKey", "CodedBasis", "CodedFrame",
    "INPUT_KINDS", "INPUT_COMMANDS",
]
