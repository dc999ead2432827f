"""The landmark calibration's own sequences (:mod:`facesculpt.app.landmark_calibration`, what
`facesculpt model calibrate` learns from) as realism-benchmark scenes, for the benchmarks that
fit them (``bench_pose_lag.py``): other identities, other texture faces, other backgrounds and
other motions than the realism benchmark's scene (:mod:`.scene`: identity seed 7, s18's first
frame, a room of s18, yaw ±25° / pitch ±10° with periods 60 / 45 frames), so that nothing learned
or chosen on them is tuned to it.

Each :data:`CALIBRATION_SCENES` entry names an identity seed, a texture (a shared video and a
frame: d0, d3 and d12 are other people than s18), a procedural background seed and a motion.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesculpt.app import landmark_calibration as lc
from facesculpt.app.landmark_calibration import Motion
from facesculpt.app.synthetic_head import procedural_background

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

#: (identity seed, texture video, texture frame, background seed, motion): the calibration's.
CALIBRATION_SCENES = tuple((lc.sequence(k)[0], video, frame, lc.sequence(k)[1], lc.sequence(k)[2])
                           for k, (video, frame) in enumerate(lc.SHARED_TEXTURES))
assert np.allclose(PIVOT, lc.PIVOT) and SIZE == lc.SIZE


@dataclass
class MovingScene(Scene):
    """A :class:`.scene.Scene` moving as its ``movement`` says."""

    movement: Motion | None = None

    def pose(self, i: int) -> tuple[float, float, np.ndarray]:
        return self.movement.pose(i)

    def to_camera(self, V: np.ndarray, i: int) -> np.ndarray:
        yaw, pitch, t = self.pose(i)
        return (np.asarray(V, np.float64) - PIVOT) @ (rotation(yaw, pitch) @ FACING).T + t


def make_calibration_scene(data: Path, entry, frames: int) -> MovingScene:
    """The scene of one :data:`CALIBRATION_SCENES` entry, ``frames`` long."""
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.fitter.calibration import uncalibrated

    seed, video, index, background, motion = entry
    model = uncalibrated(load_model("sfm"))
    photo = lc.video_frame(data / "video" / f"{video}.mp4", index)
    rest = np.asarray(random_identity(model, seed), np.float64).reshape(-1, 3)
    rest, tris, tex, outer = close_holes(rest, np.asarray(model.triangles, np.int64), fit_photo(model, photo))
    return MovingScene(rest=rest, triangles=tris, texcoords=tex, alpha=border_alpha(rest, outer), texture=photo,
                       background=procedural_background(background, SIZE), K=intrinsics(),
                       landmarks={str(k): int(v) for k, v in zip(model.landmark_names, model.landmark_vertices)},
                       frames=int(frames), model_triangles=np.asarray(model.triangles, np.int64), movement=motion)
