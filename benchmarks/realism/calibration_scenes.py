"""Synthetic sequences of their own for calibrating the landmark network's points on a model
(issue 46): other identities, other texture faces, other backgrounds and other motions than the
realism benchmark's scene (:mod:`.scene`: identity seed 7, s18's first frame, a room of s18,
yaw ±25° / pitch ±10° with periods 60 / 45 frames), so that nothing learned here is tuned to it.

Each :data:`CALIBRATION_SCENES` entry names an identity seed, a texture (a shared video and a
frame: d0, d3 and d12 are other people than s18), a procedural background seed and a motion
(yaw and pitch amplitudes, degrees, periods, frames, and phases).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .scene import (
    FACING,
    PIVOT,
    SIZE,
    Scene,
    border_alpha,
    close_holes,
    fit_photo,
    intrinsics,
    random_identity,
    rotation,
)


@dataclass
class Motion:
    """A head turning ``yaw_deg`` / ``pitch_deg`` (amplitudes) with periods (frames) and phases (rad)."""

    yaw_deg: float
    pitch_deg: float
    yaw_period: float
    pitch_period: float
    yaw_phase: float = 0.0
    pitch_phase: float = 0.0

    def pose(self, i: int) -> tuple[float, float, np.ndarray]:
        yaw = self.yaw_deg * np.sin(2 * np.pi * i / self.yaw_period + self.yaw_phase)
        pitch = self.pitch_deg * np.sin(2 * np.pi * i / self.pitch_period + self.pitch_phase)
        t = np.array([8.0 * np.sin(2 * np.pi * i / 77.0), 0.0, 560.0])
        return float(yaw), float(pitch), t


#: (identity seed, texture video, texture frame, background seed, motion)
CALIBRATION_SCENES = (
    (101, "d0", 0, 1, Motion(32.0, 14.0, 74, 53, 0.4, 1.9)),
    (202, "d3", 10, 2, Motion(28.0, 16.0, 66, 41, 2.1, 0.2)),
    (303, "d12", 5, 3, Motion(35.0, 12.0, 83, 59, 4.0, 3.1)),
)


@dataclass
class MovingScene(Scene):
    """A :class:`.scene.Scene` moving as its ``movement`` says."""

    movement: Motion | None = None

    def pose(self, i: int) -> tuple[float, float, np.ndarray]:
        return self.movement.pose(i)

    def to_camera(self, V: np.ndarray, i: int) -> np.ndarray:
        yaw, pitch, t = self.pose(i)
        return (np.asarray(V, np.float64) - PIVOT) @ (rotation(yaw, pitch) @ FACING).T + t


def video_frame(data: Path, name: str, index: int) -> np.ndarray:
    """Frame ``index`` (BGR) of the shared video ``name``."""
    cap = cv2.VideoCapture(str(data / "video" / f"{name}.mp4"))
    cap.set(cv2.CAP_PROP_POS_FRAMES, index)
    ok, frame = cap.read()
    cap.release()
    if not ok:
        raise RuntimeError(f"cannot read frame {index} of {name}.mp4")
    return frame


def procedural_background(seed: int, size=SIZE) -> np.ndarray:
    """(H, W, 3) uint8: smooth coloured noise with a few sharp-edged blocks (a room-like clutter)."""
    rng = np.random.default_rng(seed)
    W, H = size
    low = cv2.resize(rng.uniform(40, 220, (6, 8, 3)).astype(np.float32), (W, H), interpolation=cv2.INTER_CUBIC)
    img = low + rng.normal(0, 6, (H, W, 3)).astype(np.float32)
    for _ in range(6):
        x, y = rng.integers(0, W - 60), rng.integers(0, H - 60)
        w, h = rng.integers(30, 200), rng.integers(30, 200)
        img[y:y + h, x:x + w] = rng.uniform(30, 230, 3)
    return np.clip(img, 0, 255).astype(np.uint8)


def make_calibration_scene(data: Path, entry, frames: int) -> MovingScene:
    """The scene of one :data:`CALIBRATION_SCENES` entry, ``frames`` long."""
    from facesculpt.nodes.fitter import load_model

    seed, video, index, background, motion = entry
    model = load_model("sfm")
    photo = video_frame(data, video, index)
    rest = np.asarray(random_identity(model, seed), np.float64).reshape(-1, 3)
    rest, tris, tex, outer = close_holes(rest, np.asarray(model.triangles, np.int64), fit_photo(model, photo))
    return MovingScene(rest=rest, triangles=tris, texcoords=tex, alpha=border_alpha(rest, outer), texture=photo,
                       background=procedural_background(background), K=intrinsics(),
                       landmarks={str(k): int(v) for k, v in zip(model.landmark_names, model.landmark_vertices)},
                       frames=int(frames), model_triangles=np.asarray(model.triangles, np.int64), movement=motion)
