"""The faces' texture atlases and their updates from the frames: step 6 of the compositor (issue 16).

One :class:`.texture_atlas.TextureAtlas` per face key (at most MAX_FACES, then all are forgotten),
updated from the input frame every ``every`` frames by :class:`.atlas_raster.AtlasRasterizer`
(what the frame shows of each texel, and how well it sees each vertex).

With ``thread`` on (the live renderer), an update runs on a thread of its own, with an OpenGL
context of its own when one can be made: it starts once the frame is drawn (:meth:`AtlasMemory.start`,
so that it runs while the renderer waits for the next frame rather than competing with the
drawing for the cores), the render thread does none of the atlas's drawing and reading back, and
the vertices' quality it blends with is that of the last finished update (a frame or a few old;
:meth:`AtlasMemory.update`). An update is skipped while the last one runs, so the result is not
deterministic. Without an own context (or without
``thread``) the rasteriser draws on the compositor's context, on the render thread, and sees
every frame.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import moderngl
import numpy as np

from .atlas_raster import AtlasRasterizer
from .gl_context import create_headless_context
from .texture_atlas import TextureAtlas

#: Faces whose atlases are kept at once; one more and all are forgotten.
MAX_FACES = 8


class AtlasMemory:
    """AtlasMemory(ctx, size, width, height, every=1, thread=False): ``ctx`` the compositor's
    moderngl context, atlases of ``size`` texels a side for frames of ``width`` x ``height`` px,
    updated every ``every`` frames, on a thread of their own with ``thread``. :meth:`update` per
    frame, :meth:`release` at the end."""

    def __init__(self, ctx: moderngl.Context, size: int, width: int, height: int, every: int = 1,
                 thread: bool = False):
        if every < 1:
            raise ValueError(f"atlas_every must be >= 1, got {every}")
        self.size, self.every = int(size), int(every)
        self.atlases: dict = {}
        self.atlas = TextureAtlas(self.size)   # the last face's
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="atlas") if thread else None
        self._ctx = None   # the update thread's own context, when it has one
        self.raster = self._pool.submit(self._own_raster, width, height).result() if self._pool is not None else None
        if self.raster is None:   # the compositor's context draws; a thread, if any, does the CPU part
            self.raster = AtlasRasterizer(ctx, self.size, width, height)
        self._job = None
        self._pending: tuple | None = None   # the update :meth:`start` submits
        self._frames = 0
        self._quality: np.ndarray | None = None   # (V,) the last finished update's vertex quality

    def _own_raster(self, width: int, height: int) -> AtlasRasterizer | None:
        """On the update thread: a rasteriser on a context of the thread's own (:attr:`_ctx`), or
        None where no second context can be made (no EGL, a driver that refuses)."""
        try:
            self._ctx = create_headless_context()
            return AtlasRasterizer(self._ctx, self.size, width, height)
        except Exception:   # moderngl raises plain Exception subclasses per backend and driver
            if self._ctx is not None:
                self._ctx.release()
            self._ctx = None
            return None

    @property
    def current(self) -> bool:
        """Whether :meth:`update` gives this frame's vertex quality (False: the last finished update's)."""
        return self._ctx is None

    def update(self, frame: np.ndarray, fitted: np.ndarray, projected: np.ndarray, triangles: np.ndarray,
               uv: np.ndarray, face_key, keep_mask: np.ndarray | None, P: np.ndarray) -> np.ndarray:
        """Take the frame ``frame`` (H, W, 3) uint8 into the atlas of ``face_key`` (a new key: a new
        atlas) when an update is due, and return the per-vertex (V, 3) float32 (u, v, quality: the
        input's frontality, 0 where hidden) to rasterise. ``fitted`` (V, 3) camera space,
        ``projected`` (V, 2) px, ``triangles`` (T, 3) int, ``uv`` (V, 2) in [0, 1], ``keep_mask``
        (H, W) pixels not to learn (in front of the face) or None, ``P`` (3, 4) the camera that
        projects ``fitted`` to ``projected`` (:func:`.camera.estimate_projection`)."""
        uv = np.asarray(uv, np.float32)
        if uv.shape != (len(fitted), 2):
            raise ValueError(f"uv must be ({len(fitted)}, 2), got {uv.shape}")
        if self._job is not None and (self.atlas.key is None or self.atlas.key[0] != face_key):
            self._job.result()   # no reset under a running update
        if face_key not in self.atlases and len(self.atlases) >= MAX_FACES:
            self.atlases.clear()
        if face_key not in self.atlases:
            self.atlases[face_key] = self.atlas if not self.atlases and self.atlas.key is None else TextureAtlas(self.size)
        self.atlas = self.atlases[face_key]
        self.atlas.ensure(face_key, uv)
        tri = np.asarray(triangles, np.int64)
        busy = self._job is not None and not self._job.done()
        due = self._frames % self.every == 0 and not busy
        self._frames += 1
        if self._ctx is not None:
            self._pending = (self.atlas, frame, fitted, projected, tri, uv, keep_mask, P) if due else None
            return np.column_stack([uv, self._last_quality(fitted, projected, tri, P)]).astype(np.float32)
        if due:
            raw = self.raster.draw_uv(fitted, projected, tri, uv, P)
            atlas, raster = self.atlas, self.raster

            def job():
                return atlas.update(frame, *raster.finish(*raw), keep_mask)
            if self._pool is not None:
                self._job = self._pool.submit(job)
            else:
                job()
        else:
            self.raster.see(fitted, projected, tri, P)
        return np.column_stack([uv, self.raster.vertex_quality]).astype(np.float32)

    def start(self) -> None:
        """Start the update :meth:`update` found due, on the update thread with its own context
        (nothing otherwise): called once the frame is drawn."""
        if self._pending is not None:
            self._job = self._pool.submit(self._learn, *self._pending)
            self._pending = None

    def wait(self) -> None:
        """Wait for the running update, if any (e.g. before reading the atlas)."""
        if self._job is not None:
            self._job.result()

    def _learn(self, atlas: TextureAtlas, frame, fitted, projected, tri, uv, keep_mask, P) -> int:
        """On the update thread, with its own context: what the frame shows of ``atlas`` into it."""
        got = atlas.update(frame, *self.raster.observe(fitted, projected, tri, uv, P), keep_mask)
        self._quality = self.raster.vertex_quality.copy()
        return got

    def _last_quality(self, fitted, projected, tri, P) -> np.ndarray:
        """(V,) the vertex quality of the last finished update (of the running one when none has
        finished yet, or when the last was of another mesh; seen afresh on the update thread when
        that was of another mesh too)."""
        quality = self._quality
        if (quality is None or len(quality) != len(fitted)) and self._job is not None:
            self._job.result()
            quality = self._quality
        if quality is None or len(quality) != len(fitted):
            quality = self._pool.submit(lambda: self.raster.see(fitted, projected, tri, P)[0].copy()).result()
        return quality

    def release(self) -> None:
        """Wait for a running update, free the GL objects (on the thread that made them) and the thread."""
        self._pending = None
        self.wait()
        self._job = None
        if self.raster is not None:
            if self._ctx is not None:
                ctx = self._ctx
                self._pool.submit(lambda: (self.raster.release(), ctx.release())).result()
                self._ctx = None
            else:
                self.raster.release()
            self.raster = None
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
