"""The synthetic scene rendered at its own pose plus a yaw / pitch offset (the new-views and the
appearance-fitting benchmarks), in worker processes."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor

import numpy as np

from facesculpt.geometry.head_angles import euler_from_rotation, rotation_from_euler

from .raster import project, render_textured, visible_vertices
from .scene import FACING, PIVOT, Scene, rotation

_SCENE: Scene | None = None


def _init(scene: Scene) -> None:
    global _SCENE
    _SCENE = scene


def posed_vertices(scene: Scene, i: int, d_yaw: float = 0.0, d_pitch: float = 0.0) -> np.ndarray:
    """(V, 3) camera mm: frame ``i``'s head with its own yaw and pitch increased by the deltas."""
    yaw, pitch, t = scene.pose(i)
    y, p, r = euler_from_rotation(rotation(yaw, pitch) @ FACING)
    R = rotation_from_euler(y + d_yaw, p + d_pitch, r)
    return (scene.rest - PIVOT) @ R.T + t


def render_frame(job: tuple[int, float, float]) -> dict:
    """Frame ``i`` at the offset (d_yaw, d_pitch): the image, its vertices (camera mm), their pixels
    and visibility."""
    i, d_yaw, d_pitch = job
    s = _SCENE
    X = posed_vertices(s, i, d_yaw, d_pitch)
    size = (s.background.shape[1], s.background.shape[0])
    img = render_textured(s.K, X, s.triangles, s.texcoords, s.alpha, s.texture, s.background)
    return {"image": np.clip(np.rint(img), 0, 255).astype(np.uint8), "px": project(s.K, X)[0], "vertices": X,
            "visible": visible_vertices(s.K, X, s.triangles, size, tolerance_mm=3.0)}


def render_all(scene: Scene, offsets: list[tuple[float, float]], workers: int) -> dict:
    """(d_yaw, d_pitch) -> list of :func:`render_frame` results for every frame."""
    jobs = [(i, dy, dp) for dy, dp in offsets for i in range(scene.frames)]
    with ProcessPoolExecutor(workers, initializer=_init, initargs=(scene,)) as pool:
        done = list(pool.map(render_frame, jobs, chunksize=4))
    out = {}
    for (_, dy, dp), frame in zip(jobs, done):
        out.setdefault((dy, dp), []).append(frame)
    return out


