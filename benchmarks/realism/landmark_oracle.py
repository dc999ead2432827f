"""The landmark detector's share of what the fit costs (``bench_realism.py --landmark-oracle KEEP``).

``process`` runs as a user runs it, except that in every frame of the synthetic video the
detector's inner iBUG points (18-68, those with a landmark vertex of the Surrey model) are moved
toward where the true head's landmark vertices are: ``truth + KEEP * (detected - truth)``, so
KEEP 0 gives the true points and 1 the detector's own. The jaw line (iBUG 1-17) stays the
detector's: it follows the silhouette, which no fixed vertex marks. The face mesh's fit takes
all 468 network points, so the oracle is for the Surrey model (``--models sfm``) only.

Run as ``python -m realism.landmark_oracle process ...`` (``benchmarks/`` on PYTHONPATH) with
:data:`LANDMARKS_ENV` naming a file written by :func:`write_true_landmarks` and :data:`KEEP_ENV`
the share kept; :func:`process_environment` gives both. The frame index is the count of
:meth:`LandmarkDetector.track` calls since the detector's last ``reset`` (``process`` resets it
before each pass over the video: the neutral's, then the edit's).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from .raster import project_pixels

#: Environment variables the oracle's process reads: the true landmarks (.npz) and KEEP.
LANDMARKS_ENV = "FACESCULPT_BENCH_TRUE_LANDMARKS"
KEEP_ENV = "FACESCULPT_BENCH_LANDMARK_KEEP"
#: The module ``run_process`` runs instead of ``facesculpt.cli``.
MODULE = "benchmarks.realism.landmark_oracle"
#: iBUG points (0-based) whose truth is a vertex: the jaw line (0-16) is a silhouette.
INNER = range(17, 68)


def true_landmarks(scene) -> np.ndarray:
    """(F, 68, 2) float64 px: where the true head's iBUG landmark vertices are in each of ``scene``'s
    frames (unedited), in the project's pixel convention (centres at integers, as the detector's
    points), NaN for the jaw line and for points the model has no vertex for."""
    rows = [k for k in INNER if str(k + 1) in scene.landmarks]
    vertices = [scene.landmarks[str(k + 1)] for k in rows]
    out = np.full((scene.frames, 68, 2), np.nan)
    for i in range(scene.frames):
        out[i, rows] = project_pixels(scene.K, scene.to_camera(scene.rest[vertices], i))
    return out


def write_true_landmarks(path: Path, truth: np.ndarray, size: tuple[int, int]) -> Path:
    """Write ``truth`` (F, 68, 2) px of frames of ``size`` (W, H) for the oracle's process."""
    np.savez(path, points=truth, size=np.asarray(size, np.int64))
    return Path(path)


def process_environment(path: Path, keep: float) -> dict[str, str]:
    """The environment variables that make ``python -m`` :data:`MODULE` find the true landmarks
    at ``path`` and keep ``keep`` of the detector's error (the checkout's root first on PYTHONPATH)."""
    here = str(Path(__file__).resolve().parents[2])
    pythonpath = os.pathsep.join(p for p in (here, os.environ.get("PYTHONPATH", "")) if p)
    return {LANDMARKS_ENV: str(Path(path).resolve()), KEEP_ENV: repr(float(keep)), "PYTHONPATH": pythonpath}


def move_toward_truth(points: np.ndarray, truth: np.ndarray, keep: float) -> np.ndarray:
    """``points`` (468, k) face-mesh points, px, with the mesh points the iBUG mapping reads for
    the finite rows of ``truth`` (68, 2) moved to ``truth + keep * (point - truth)``."""
    from facesculpt.geometry.ibug68 import IBUG68_FROM_MESH

    rows = np.flatnonzero(np.isfinite(truth[:, 0]))
    m = IBUG68_FROM_MESH[rows]   # one mesh point per iBUG point
    out = np.array(points, np.float64)
    out[m, :2] = truth[rows] + keep * (out[m, :2] - truth[rows])
    return out.astype(np.asarray(points).dtype)


def install(truth: np.ndarray, size: tuple[int, int], keep: float) -> None:
    """Make every :class:`LandmarkDetector` of this process move its first face's inner points
    toward ``truth`` (F, 68, 2) in frames of ``size`` (W, H) (other frames, and frames past F,
    keep the detector's points)."""
    from facesculpt.nodes.landmarks.detector import LandmarkDetector

    track, reset = LandmarkDetector.track, LandmarkDetector.reset
    count = [0]

    def tracked(self, frame, *args, **kwargs):
        faces = track(self, frame, *args, **kwargs)
        i, count[0] = count[0], count[0] + 1
        if faces and i < len(truth) and (frame.shape[1], frame.shape[0]) == tuple(size):
            faces[0].points = move_toward_truth(faces[0].points, truth[i], keep)
        return faces

    def reset_count(self, *args, **kwargs):
        count[0] = 0
        return reset(self, *args, **kwargs)

    LandmarkDetector.track, LandmarkDetector.reset = tracked, reset_count


def main() -> int:
    """facesculpt's command line (``sys.argv[1:]``) with the oracle installed from the environment."""
    got = np.load(os.environ[LANDMARKS_ENV])
    install(got["points"], tuple(int(x) for x in got["size"]), float(os.environ[KEEP_ENV]))
    from facesculpt.cli import main as facesculpt_main

    sys.argv[0] = "facesculpt"
    return facesculpt_main()


if __name__ == "__main__":
    sys.exit(main())
