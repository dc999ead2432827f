"""Learning a model's landmark calibration from renders at known pose (`facesculpt model calibrate`,
issue 46): where the landmark network's point for each named landmark lies on the model.

For each texture photo, a synthetic head (:mod:`.synthetic_head`: the model's random identity,
textured from the face in the photo, over a procedural background) turns before a 60° camera
through a motion of its own (:data:`MOTIONS`: yaw ±28-35°, pitch ±12-16°, other periods and
phases, 560 mm away). Each frame is rendered with the reference rasteriser
(:func:`facesculpt.geometry.raster.render_textured`) and the network's 468 points are tracked on
it; :func:`facesculpt.nodes.fitter.calibration.learn_calibration` then gives each fixed iBUG
landmark its offset from its vertex (mm) and its weight, and the network's rigid points' turn
against the true one gives its rotation gain.

None of this is the realism benchmark's scene (identity seed 7, s18's first frame, a room of s18,
yaw ±25° / pitch ±10°, 510 mm): the default textures (:data:`SHARED_TEXTURES`) are frames of other
people's shared videos, so that a calibration built here is not tuned to the benchmark.
"""

from __future__ import annotations

import datetime
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from facesculpt.app.synthetic_head import (
    FACING,
    border_alpha,
    close_holes_with_centres,
    intrinsics,
    painted_points,
    photo_fit,
    procedural_background,
    random_identity,
    rotation,
)

#: Rendered frame size (W, H) px and horizontal field of view, degrees.
SIZE = (640, 480)
FOV_DEG = 60.0
#: The point the head turns about (model space, mm: behind the face).
PIVOT = np.array([0.0, 0.0, -90.0])
#: Frames per sequence (25 frames/s) unless told otherwise.
FRAMES = 80
#: Default texture photos: (shared video, frame): d0, d3 and d12 are other people than the realism
#: benchmark's s18.
SHARED_TEXTURES = (("d0", 0), ("d3", 10), ("d12", 5))


@dataclass(frozen=True)
class Motion:
    """A head turning ``yaw_deg`` / ``pitch_deg`` (amplitudes, degrees) with periods (frames) and
    phases (rad), drifting sideways 8 mm, ``distance_mm`` from the camera."""

    yaw_deg: float
    pitch_deg: float
    yaw_period: float
    pitch_period: float
    yaw_phase: float = 0.0
    pitch_phase: float = 0.0
    distance_mm: float = 560.0

    def pose(self, i: int) -> tuple[float, float, np.ndarray]:
        """Frame ``i``'s yaw, pitch (degrees) and head translation (3,) camera mm."""
        yaw = self.yaw_deg * np.sin(2 * np.pi * i / self.yaw_period + self.yaw_phase)
        pitch = self.pitch_deg * np.sin(2 * np.pi * i / self.pitch_period + self.pitch_phase)
        t = np.array([8.0 * np.sin(2 * np.pi * i / 77.0), 0.0, self.distance_mm])
        return float(yaw), float(pitch), t


#: Sequence k (of texture k): (identity seed, background seed, motion); more textures than
#: sequences reuse the motions with other seeds.
MOTIONS = (
    (101, 1, Motion(32.0, 14.0, 74, 53, 0.4, 1.9)),
    (202, 2, Motion(28.0, 16.0, 66, 41, 2.1, 0.2)),
    (303, 3, Motion(35.0, 12.0, 83, 59, 4.0, 3.1)),
)


@dataclass
class Head:
    """A textured head (:mod:`.synthetic_head`): rest vertices (V, 3) model mm (the model's own
    first, then the centres of the fans that close its holes), triangles (T, 3), texture
    coordinates (V, 2) px into ``texture`` (BGR), per-vertex alpha (V,), a background (H, W, 3),
    and ``landmarks`` (68, 3) model mm: where the face's own iBUG points (the network's on the
    photo) are painted on the head (NaN where off it)."""

    rest: np.ndarray
    triangles: np.ndarray
    texcoords: np.ndarray
    alpha: np.ndarray
    texture: np.ndarray
    background: np.ndarray
    landmarks: np.ndarray


def video_frame(path: Path, index: int) -> np.ndarray:
    """Frame ``index`` (BGR) of the video at ``path``; RuntimeError when it cannot be read."""
    cap = cv2.VideoCapture(str(path))
    cap.set(cv2.CAP_PROP_POS_FRAMES, index)
    ok, frame = cap.read()
    cap.release()
    if not ok:
        raise RuntimeError(f"cannot read frame {index} of {path}")
    return frame


def shared_textures(data: Path) -> list[np.ndarray]:
    """The default texture photos (:data:`SHARED_TEXTURES`) from the shared data folder ``data``."""
    return [video_frame(data / "video" / f"{name}.mp4", index) for name, index in SHARED_TEXTURES]


def sequence(k: int) -> tuple[int, int, Motion]:
    """Sequence ``k``'s identity seed, background seed and motion (:data:`MOTIONS`)."""
    seed, background, motion = MOTIONS[k % len(MOTIONS)]
    return seed + 1000 * (k // len(MOTIONS)), background + 10 * (k // len(MOTIONS)), motion


def make_head(model, texture: np.ndarray, seed: int, background: int) -> Head:
    """The textured head of identity ``seed`` (a sparse ``model``), its texture the face in
    ``texture``, over procedural background ``background``. RuntimeError when the photo shows no
    face."""
    from facesculpt.nodes.fitter.calibration import uncalibrated

    rest = np.asarray(random_identity(model, seed), np.float64).reshape(-1, 3)
    uv, depth, points = photo_fit(uncalibrated(model), texture, FOV_DEG)
    painted = painted_points(uv, depth, np.asarray(model.triangles, np.int64), rest, points)
    rest, tris, tex, outer = close_holes_with_centres(rest, np.asarray(model.triangles, np.int64), uv)
    return Head(rest, tris, tex, border_alpha(rest, outer), texture, procedural_background(background, SIZE), painted)


def poses(motion: Motion, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """(R (F, 3, 3), c (F, 3)): camera = R @ X + c for model-space X mm, over ``frames`` frames."""
    R, c = [], []
    for i in range(frames):
        yaw, pitch, t = motion.pose(i)
        Ri = rotation(yaw, pitch) @ FACING
        R.append(Ri)
        c.append(t - Ri @ PIVOT)
    return np.array(R), np.array(c)


_HEAD: Head | None = None   # the head a rendering worker process draws (set by its initializer)


def _init_worker(head: Head) -> None:
    global _HEAD
    _HEAD = head


def _render(job: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    from facesculpt.geometry.raster import render_textured

    R, c = job
    h = _HEAD
    X = h.rest @ R.T + c
    img = render_textured(intrinsics(SIZE, FOV_DEG), X, h.triangles, h.texcoords, h.alpha, h.texture, h.background)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def render(head: Head, R: np.ndarray, c: np.ndarray, workers: int) -> list[np.ndarray]:
    """The head at each pose (R (F, 3, 3), c (F, 3)): (H, W, 3) uint8 BGR frames, rendered in
    ``workers`` processes."""
    with ProcessPoolExecutor(max(1, workers), initializer=_init_worker, initargs=(head,)) as pool:
        return list(pool.map(_render, list(zip(R, c)), chunksize=4))


def track(frames: list[np.ndarray]) -> np.ndarray:
    """(F, 468, 3) the landmark network's points (x, y px, relative depth px) tracked over
    ``frames``, NaN where no face was found."""
    from facesculpt.nodes.landmarks.detector import LandmarkDetector

    detector = LandmarkDetector()
    out = np.full((len(frames), 468, 3), np.nan)
    for i, frame in enumerate(frames):
        faces = detector.track(frame)
        if faces:
            out[i] = np.asarray(faces[0].points, np.float64)[:, :3]
    return out


def sequences(model, textures: list[np.ndarray], frames: int = FRAMES, workers: int = 0, progress=None,
              painted: bool = True) -> list[dict]:
    """One calibration sequence per texture photo (BGR): a dict with ``K``, ``R``, ``c``,
    ``observed`` (F, L, 2) px (the network's points of the model's fixed landmarks,
    :func:`~facesculpt.nodes.fitter.calibration.fixed_landmarks`), ``vertices`` (L, 3) mm (what
    the offsets are learned from: with ``painted``, where the photo's own landmarks are painted on
    the head, so that the texture fit's misregistration is not learned as the network's offset;
    else the head's landmark vertices), ``landmark_vertices`` (L, 3) mm (the latter), ``points``
    (F, 468, 3) (all the network's points), ``yaw`` (F,) degrees and ``source`` (what it is, in
    words). ``progress(done, total)`` is called after each sequence."""
    from facesculpt.geometry.ibug68 import IBUG68_FROM_MESH
    from facesculpt.nodes.fitter.calibration import fixed_landmarks

    names = fixed_landmarks(model)
    if not names:
        raise ValueError(f"model {model.model_id} has no iBUG landmarks (1-68) with a fixed vertex to calibrate")
    index = {n: i for i, n in enumerate(model.landmark_names)}
    vertices = np.asarray(model.landmark_vertices)[[index[n] for n in names]]
    workers = workers or max(1, min(4, len(os.sched_getaffinity(0))))
    out = []
    for k, texture in enumerate(textures):
        seed, background, motion = sequence(k)
        head = make_head(model, texture, seed, background)
        R, c = poses(motion, frames)
        points = track(render(head, R, c, workers))
        ibug = [int(n) - 1 for n in names]
        reference = head.rest[vertices].copy()
        if painted:
            ok = np.isfinite(head.landmarks[ibug]).all(axis=1)
            reference[ok] = head.landmarks[ibug][ok]
        out.append({"K": intrinsics(SIZE, FOV_DEG), "R": R, "c": c, "points": points,
                    "observed": points[:, IBUG68_FROM_MESH[ibug], :2], "vertices": reference,
                    "landmark_vertices": head.rest[vertices], "yaw": np.array([motion.pose(i)[0] for i in range(frames)]),
                    "source": f"identity seed {seed}, background {background}, yaw +-{motion.yaw_deg:g} "
                              f"pitch +-{motion.pitch_deg:g} deg"})
        if progress is not None:
            progress(k + 1, len(textures))
    return out


def learn(model, seqs: list[dict], what: str):
    """``model`` calibrated from the sequences (:func:`sequences`), its provenance saying ``what``
    the textures were: (the calibrated model, the learned figures: ``offsets``, ``sigma``,
    ``weights``, ``rotation_slopes`` (pitch, yaw), ``names``)."""
    import facesculpt
    from facesculpt.geometry.ibug68 import IBUG68_FROM_MESH
    from facesculpt.nodes.fitter.calibration import calibrated, fixed_landmarks, learn_calibration, network_rotation
    from facesculpt.nodes.fitter.detector_rotation import RIGID_IDS

    names = fixed_landmarks(model)
    learned = learn_calibration(seqs)
    rigid = IBUG68_FROM_MESH[[int(n) - 1 for n in RIGID_IDS]]
    slopes = [network_rotation(s["points"], s["R"], 1.0, rigid) for s in seqs]
    learned["rotation_slopes"] = np.mean([(t["pitch_slope"], t["yaw_slope"]) for t in slopes], axis=0)
    learned["names"] = names
    gain = np.r_[1.0 / learned["rotation_slopes"], 1.0]
    frames = len(seqs[0]["R"]) if seqs else 0
    provenance = (f"facesculpt model calibrate (facesculpt {getattr(facesculpt, '__version__', '?')}, "
                  f"{datetime.date.today().isoformat()}): the face-mesh network's points on {len(seqs)} synthetic "
                  f"sequences of {frames} frames, textures {what}; " + "; ".join(s["source"] for s in seqs))
    return calibrated(model, names, learned["offsets"], learned["weights"], provenance, gain), learned


def save_builtin(model, path: Path) -> Path:
    """Write the calibration of ``model`` (an on-the-fly model such as ``sfm``, calibrated by
    :func:`learn`) to ``path``, where ``load_model`` reads it (its fixed landmarks only)."""
    from facesculpt.nodes.fitter.calibration import fixed_landmarks, save_calibration

    names = fixed_landmarks(model)
    rows = [model.landmark_names.index(n) for n in names]
    return save_calibration(path, model.model_id, names, model.landmark_offsets[rows], model.landmark_weights[rows],
                            model.calibration, model.network_rotation_gain)


def build_sfm_calibration(data: Path, path: Path, frames: int = FRAMES, workers: int = 0, progress=None) -> Path:
    """The Surrey model's calibration from the shared data folder ``data`` (its model files and
    the default textures, :data:`SHARED_TEXTURES`), written to ``path`` (what `facesculpt setup`
    builds when the shared data is there)."""
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.fitter.calibration import uncalibrated

    model = uncalibrated(load_model("sfm"))
    what = "the shared data's " + ", ".join(f"{v} frame {i}" for v, i in SHARED_TEXTURES)
    calibrated, _ = learn(model, sequences(model, shared_textures(data), frames, workers, progress), what)
    return save_builtin(calibrated, path)
