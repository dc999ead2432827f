"""The synthetic scene: the Surrey Face Model with a random identity, textured from a real face
(a frame of ../shared/data/video/s18.mp4, fitted with the project's landmarks and SFM fitter:
analysis only), over a real background (a face-free region of the same frame), turning smoothly
(yaw ±25°, pitch ±10°; or held nearly still, :data:`MOTIONS`) in front of a pinhole camera with a
60° horizontal field of view (the default ``facesculpt process --fov``).

Model space is the SFM's: mm, x to the subject's left, y up, z out of the face.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from facesculpt.app.synthetic_head import (  # noqa: F401 (FACING, BORDER_FADE_MM, rotation: re-exported)
    BORDER_FADE_MM,
    FACING,
    border_alpha,
    fit_photo,
    random_identity,
    rotation,
)
from facesculpt.app.synthetic_head import close_holes_with_centres as close_holes
from facesculpt.app.synthetic_head import intrinsics as head_intrinsics

#: Output frame size (W, H) px, frame rate.
SIZE = (640, 480)
FPS = 25
#: Horizontal field of view, degrees (that of ``process --fov``'s default).
FOV_DEG = 60.0
#: Head motion: amplitudes (degrees) and periods (frames) of yaw and pitch; sideways drift (mm).
YAW_DEG, YAW_PERIOD = 25.0, 60
PITCH_DEG, PITCH_PERIOD = 10.0, 45
DRIFT_MM, DRIFT_PERIOD = 12.0, 90
#: The head's motions: "turning" (the amplitudes above), or "still" (a head held nearly still,
#: swaying by STILL_SHARE of them at STILL_PACE of their pace about a pose turned a little: jitter
#: shows where true motion is smooth).
MOTIONS = ("turning", "still")
STILL_SHARE, STILL_PACE = 0.1, 1.0 / 3.0
STILL_YAW_DEG, STILL_PITCH_DEG = 8.0, 3.0
#: The point the head turns about (model space, mm: behind the face) and its distance (mm).
PIVOT = np.array([0.0, 0.0, -90.0])
DISTANCE_MM = 510.0


@dataclass
class Scene:
    """Everything that renders a frame: the head's rest vertices (V, 3) model mm, triangles
    (T, 3), texture coordinates (V, 2) px into ``texture`` (h, w, 3) uint8 BGR, per-vertex
    alpha (V,), the background (H, W, 3) uint8 BGR, intrinsics K (3, 3), landmark name ->
    vertex, the number of frames, and the model's own triangles (its first vertices are the
    model's; ``triangles`` adds fans that close the mouth)."""

    rest: np.ndarray
    triangles: np.ndarray
    texcoords: np.ndarray
    alpha: np.ndarray
    texture: np.ndarray
    background: np.ndarray
    K: np.ndarray
    landmarks: dict[str, int]
    frames: int
    model_triangles: np.ndarray
    motion: str = "turning"

    @property
    def model_vertices(self) -> int:
        """The number of the model's own vertices: ``rest``'s first rows (the rest are the centres
        of the fans that close the mouth)."""
        return int(self.model_triangles.max()) + 1

    def pose(self, i: int) -> tuple[float, float, np.ndarray]:
        """Frame ``i``'s yaw, pitch (degrees) and head translation (3,) camera mm."""
        return head_pose(i, self.motion)

    def to_camera(self, V: np.ndarray, i: int) -> np.ndarray:
        """Model-space vertices (V, 3) mm into frame ``i``'s camera space (V, 3) mm."""
        yaw, pitch, t = head_pose(i, self.motion)
        R = rotation(yaw, pitch) @ FACING
        return (np.asarray(V, np.float64) - PIVOT) @ R.T + t


def head_pose(i: int, motion: str = "turning") -> tuple[float, float, np.ndarray]:
    """Yaw, pitch (degrees) and translation (3,) camera mm of frame ``i`` of the head's ``motion``
    (one of :data:`MOTIONS`)."""
    if motion not in MOTIONS:
        raise ValueError(f"the head's motion must be one of {MOTIONS}, got {motion!r}")
    # the still head also sways at a fraction of the turning one's pace: smooth at any frame
    share, pace, yaw0, pitch0 = ((1.0, 1.0, 0.0, 0.0) if motion == "turning"
                                 else (STILL_SHARE, STILL_PACE, STILL_YAW_DEG, STILL_PITCH_DEG))
    yaw = yaw0 + share * YAW_DEG * np.sin(2 * np.pi * pace * i / YAW_PERIOD)
    pitch = pitch0 + share * PITCH_DEG * np.sin(2 * np.pi * pace * i / PITCH_PERIOD + 0.6)
    t = np.array([share * DRIFT_MM * np.sin(2 * np.pi * pace * i / DRIFT_PERIOD), 6.0, DISTANCE_MM])
    return float(yaw), float(pitch), t


def intrinsics(size=SIZE, fov_deg: float = FOV_DEG) -> np.ndarray:
    """(3, 3) intrinsics of the scene's camera (:func:`facesculpt.app.synthetic_head.intrinsics`)."""
    return head_intrinsics(size, fov_deg)


def source_frame(data: Path) -> np.ndarray:
    """The first frame of s18.mp4 (1280x720 BGR): the texture's face and the background."""
    cap = cv2.VideoCapture(str(data / "video" / "s18.mp4"))
    ok, frame = cap.read()
    cap.release()
    if not ok:
        raise RuntimeError(f"cannot read {data / 'video' / 's18.mp4'}")
    return frame


def background_from(frame: np.ndarray, size=SIZE) -> np.ndarray:
    """A face-free region of s18's first frame (the room left of the person), resized to
    ``size`` (W, H)."""
    W, H = size
    crop = frame[140:140 + 372, 0:496]
    return cv2.resize(crop, (W, H), interpolation=cv2.INTER_CUBIC)


def make_scene(data: Path, frames: int = 90, seed: int = 7, motion: str = "turning") -> Scene:
    """The benchmark's scene from the shared data folder ``data`` (../shared/data), the head moving
    as ``motion`` says (:data:`MOTIONS`)."""
    head_pose(0, motion)   # an unknown motion fails here, before the texture's fit
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.fitter.calibration import uncalibrated

    model = uncalibrated(load_model("sfm"))   # the texture's fit: the same with or without a calibration
    frame = source_frame(data)
    rest = np.asarray(random_identity(model, seed), np.float64).reshape(-1, 3)
    rest, tris, tex, outer = close_holes(rest, np.asarray(model.triangles, np.int64), fit_photo(model, frame))
    return Scene(rest=rest, triangles=tris, texcoords=tex, alpha=border_alpha(rest, outer),
                 texture=frame, background=background_from(frame), K=intrinsics(),
                 landmarks={str(k): int(v) for k, v in zip(model.landmark_names, model.landmark_vertices)},
                 frames=int(frames), model_triangles=np.asarray(model.triangles, np.int64), motion=motion)
