"""Frame-to-frame jitter of a fitted mesh, and what a video adds to it (the appearance-fitting
benchmark, issue 20).

* :func:`jitter`: the metric. The fitted pixels' smooth motion (a Gaussian over ±3 frames) is
  removed; the median vertex's displacement from one frame to the next of what remains, on the
  frames whose smooth motion is slow.
* :func:`degraded`: frames as a camera and a codec give them, for a synthetic clip whose true
  motion is smooth (so that all its jitter is the fit's): Gaussian camera noise, then H.264.
* :func:`tracked_motion`: a reference for real video, whose true motion is unknown. The face's
  own image motion from frame to frame (corners on it tracked with Lucas-Kanade as the refinement
  tracks them, an affine motion fitted to them) carried along from the first frame; its jitter is what a tracker that follows
  the pixels faithfully shows by the same metric, and :func:`low_passed` what is left of it
  through the fitter's smoothing of a still head.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

#: A frame is still when the fitted mesh's smooth motion moves its median vertex less than this (px).
STILL_PX = 1.0
#: Image conditions of the synthetic clip: camera noise (standard deviation, grey levels) and
#: the H.264 quality (CRF) it is encoded with (None: not encoded).
CONDITIONS = {"clean": (0.0, None), "camera noise": (3.0, None), "camera noise, H.264": (3.0, 23)}
#: Huber scale (px) of the affine fit to the tracked corners, and the corners picked per frame at most.
TRACK_HUBER_PX = 0.3
TRACK_CORNERS = 300


def _smooth(tracks: np.ndarray) -> np.ndarray:
    """(F, V, 2) the smooth motion of ``tracks`` (F, V, 2): a Gaussian over ±3 frames."""
    return cv2.GaussianBlur(tracks.reshape(len(tracks), -1), (1, 7), 0, sigmaY=1.5).reshape(tracks.shape)


def still_steps(tracks: np.ndarray, still_px: float = STILL_PX) -> np.ndarray:
    """(F - 1,) bool: the steps from one frame of ``tracks`` (F, V, 2) px to the next where the smooth
    motion moves the median vertex less than ``still_px`` px (none within the filter's ends)."""
    speed = np.median(np.linalg.norm(np.diff(_smooth(tracks), axis=0), axis=2), axis=1)
    still = speed < still_px
    still[:3] = still[-3:] = False
    return still


def jitter(tracks: np.ndarray, still_px: float = STILL_PX, still: np.ndarray | None = None) -> tuple[float, int]:
    """(median jitter px, frames it is taken over) of a fitted mesh's pixels ``tracks`` (F, V, 2) over
    consecutive frames: the smooth motion (a Gaussian over ±3 frames) removed, the median vertex
    displacement of what remains from one frame to the next, on the still steps (``still`` (F - 1,)
    bool, by default :func:`still_steps` of ``tracks`` with ``still_px``); NaN without any."""
    tracks = np.asarray(tracks, np.float64)
    rest = tracks - _smooth(tracks)
    step = np.median(np.linalg.norm(np.diff(rest, axis=0), axis=2), axis=1)
    still = still_steps(tracks, still_px) if still is None else np.asarray(still, bool)[:len(step)]
    return (float(np.median(step[still])) if still.any() else float("nan")), int(still.sum())


def degraded(frames: list, noise: float, crf: int | None, folder: Path, seed: int = 0) -> list:
    """``frames`` ((H, W, 3) uint8 BGR) with Gaussian noise of ``noise`` grey levels (a fixed
    ``seed``), then encoded as H.264 at quality ``crf`` by the project's own writer and read back
    as ``process`` reads (None: not encoded); the video is written into ``folder``."""
    from facesculpt.nodes.renderer.video_out import VideoOutput

    from .sequences import read_video

    rng = np.random.default_rng(seed)
    out = [np.clip(f + rng.normal(0.0, noise, f.shape), 0, 255).astype(np.uint8) if noise else f for f in frames]
    if crf is None:
        return out
    path = Path(folder) / f"degraded_noise{noise:g}_crf{crf}.mp4"
    with VideoOutput(path, 25.0, codec="libx264", crf=int(crf)) as video:
        for frame in out:
            video.write(frame)
    h, w = frames[0].shape[:2]
    return [frame[:h, :w] for frame in read_video(path)]   # the writer pads an odd side by one


def affine_motion(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(2, 3) the affine map taking the points ``a`` (P, 2) to ``b`` (P, 2) px, least squares with
    Huber weights beyond TRACK_HUBER_PX (a corner on a moving mouth counts less)."""
    A = np.c_[a, np.ones(len(a))]
    w = np.ones(len(a))
    for _ in range(6):
        M = np.linalg.lstsq(A * np.sqrt(w)[:, None], b * np.sqrt(w)[:, None], rcond=None)[0].T
        r = np.linalg.norm(a @ M[:, :2].T + M[:, 2] - b, axis=1)
        w = 1.0 / np.maximum(1.0, r / TRACK_HUBER_PX)
    return M


def tracked_motion(frames: list, projected: np.ndarray) -> np.ndarray:
    """(F, V, 2) px: the first frame's fitted pixels ``projected[0]`` carried from frame to frame
    of ``frames`` ((H, W, 3) uint8 BGR) by the face's own image motion: up to TRACK_CORNERS corners
    inside each frame's fitted face (``projected`` (F, V, 2) px), picked and tracked forward and
    back as the appearance refinement's are (:mod:`facesculpt.nodes.fitter.surface_features`), and
    an affine motion fitted to those that return (the last one again when fewer than 6 do)."""
    from facesculpt.nodes.fitter.surface_features import surface_features, track_features

    greys = [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in frames]
    total, M = np.eye(3), np.c_[np.eye(2), np.zeros(2)]
    first = np.asarray(projected[0], np.float64)
    out = [first]
    for i in range(1, len(greys)):
        every = np.ones(len(projected[i - 1]), bool)
        corners = surface_features(greys[i - 1], projected[i - 1], every, max_features=TRACK_CORNERS)
        if corners is not None:
            found, kept, _ = track_features(greys[i - 1], greys[i], corners)
            if kept.sum() >= 6:
                M = affine_motion(corners.pixels[kept], found[kept])
        total = np.vstack([M, [0.0, 0.0, 1.0]]) @ total
        out.append(first @ total[:2, :2].T + total[:2, 2])
    return np.array(out)


def low_passed(tracks: np.ndarray, cutoff_hz: float, fps: float = 25.0) -> np.ndarray:
    """(F, V, 2) ``tracks`` through a first-order low-pass at ``cutoff_hz``: the One Euro filter the
    fitter smooths with, at its minimum cutoff (where a still head keeps it)."""
    from facesculpt.nodes.fitter.smoothing import OneEuroFilter

    smooth = OneEuroFilter(cutoff_hz, 0.0)
    return np.array([smooth(x, i / fps) for i, x in enumerate(np.asarray(tracks, np.float64))])
