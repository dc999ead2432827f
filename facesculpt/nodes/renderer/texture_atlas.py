"""The texture memory of a face: its best observation per texel of the model's UV space, over
the frames (issue 16; docs/architecture.md "Stages", 4).

Plain arrays in and out, no GL, no I/O. Each update takes what one frame saw of the atlas (per
texel: the frame pixel it lands on and how well it was seen there, from :mod:`.atlas_raster`)
and the frame itself:

* **quality** of an observation: frontality (cosine of the surface normal with the view ray)
  times size (frame pixels per texel, linear, capped at 1), 0 where the texel was hidden
  (z-buffer) or outside the frame; pixels of the ``keep_mask`` (what is in front of the face,
  e.g. a hand) are not observed at all;
* **best observation**: a texel takes an observation at least ``keep_ratio`` as good as the
  best it has seen (``best``), averaged with the earlier ones by quality (at most ``max_weight``
  of them count: recent frames win); an observation ``replace_ratio`` better than the best
  replaces the average outright; ``best`` and the weights decay by ``decay`` per update so that
  the atlas keeps up with a face that changes slowly;
* **colour correction**: the atlas keeps the lighting of its first frame. Each frame's colours
  are brought to it by a per-channel gain (the ratio of the means of atlas and frame on the
  texels both see well), and :meth:`TextureAtlas.image` with ``lighting="frame"`` gives the
  atlas in the last frame's lighting (what the compositor blends in);
* **reset** when the face changes (:meth:`TextureAtlas.ensure` with another face key or UV
  layout).

UV layout (:func:`uv_layout`): the model's texture coordinates where it has them (the Surrey
Face Model); else a frontal orthographic projection of the model's neutral, scaled uniformly
into the unit square with a margin (the built-in ``facemesh`` model's neutral, before a
person's is learned, is a flat Tutte embedding of its tessellation: the layout is that
embedding). u runs right, v down: texel (row, col) = (v, u) * size.

Shapes: atlas (S, S, 3) float32 BGR 0..255; per-texel maps (S, S) float32; texel pixels
(S, S, 2) float32 frame pixels (x, y), NaN where no triangle covers the texel.
"""

from __future__ import annotations

import cv2
import numpy as np

UV_MARGIN = 0.02  # share of the unit square left free around a derived layout
ATLAS_STRETCH = (1.5, 3.0)   # source-map stretch (linear) from which the atlas starts / fully takes over
ATLAS_GRAZING = 0.35         # input-view frontality (cosine, 0 where hidden) under which the atlas takes over
CONFIDENT = (0.35, 0.7)  # best quality from which a texel's confidence rises from 0, and where it is 1


def uv_layout(neutral: np.ndarray, texcoords: np.ndarray | None = None) -> np.ndarray:
    """(V, 2) float32 texture coordinates in [0, 1]: ``texcoords`` (V, 2) when given and as many
    as the vertices (flipped so v runs down when they follow OpenGL's v-up convention is the
    caller's business: they are used as they are), else the frontal orthographic projection of
    ``neutral`` (V, 3) model space (x right on the image of the layout, y up), scaled uniformly
    into [UV_MARGIN, 1 - UV_MARGIN]."""
    neutral = np.asarray(neutral, np.float64).reshape(-1, 3)
    if texcoords is not None and len(texcoords) == len(neutral) and len(neutral):
        return np.asarray(texcoords, np.float32).reshape(-1, 2)
    xy = neutral[:, :2] * np.array([1.0, -1.0])
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    span = float(max((hi - lo).max(), 1e-9))
    uv = (xy - (lo + hi) / 2) / span * (1 - 2 * UV_MARGIN) + 0.5
    return uv.astype(np.float32)


class TextureAtlas:
    """The atlas of one face. TextureAtlas(size=256, ...): ``size`` texels a side; the others as
    in the module docstring (``min_quality``: observations below it are ignored; ``gain_limits``
    the range of the per-channel gain; ``min_overlap`` texels both seen well needed to estimate
    it, else the last gain is kept).

    State (read freely): ``colour`` (S, S, 3) float32, ``weight`` and ``best`` (S, S) float32,
    ``gain`` (3,) float32 (frame colour x gain = atlas colour), ``key`` (face key, layout hash),
    ``updates`` (frames taken since the reset)."""

    def __init__(self, size: int = 256, *, min_quality: float = 0.3, keep_ratio: float = 0.6,
                 replace_ratio: float = 1.4, max_weight: float = 3.0, decay: float = 0.998,
                 gain_limits: tuple[float, float] = (0.5, 2.0), min_overlap: int = 200):
        if not 16 <= int(size) <= 4096:
            raise ValueError(f"atlas size must be 16 to 4096 texels, got {size}")
        self.size = int(size)
        self.min_quality, self.keep_ratio, self.replace_ratio = float(min_quality), float(keep_ratio), float(replace_ratio)
        self.max_weight, self.decay = float(max_weight), float(decay)
        self.gain_limits, self.min_overlap = tuple(map(float, gain_limits)), int(min_overlap)
        self.key = None
        self.reset()

    def reset(self, key=None) -> None:
        """Forget everything (a new face): empty atlas, gain 1, ``key`` remembered."""
        S = self.size
        self.colour = np.zeros((S, S, 3), np.float32)
        self.weight = np.zeros((S, S), np.float32)
        self.best = np.zeros((S, S), np.float32)
        self.gain = np.ones(3, np.float32)
        self.key = key
        self.updates = 0

    def ensure(self, face_key, uv: np.ndarray) -> bool:
        """Reset when ``face_key`` or the layout ``uv`` (V, 2) differs from the atlas's; True when
        it reset."""
        uv = np.ascontiguousarray(uv, np.float32)
        key = (face_key, uv.shape, hash(uv.tobytes()))
        if key == self.key:
            return False
        self.reset(key)
        return True

    def observe(self, frame: np.ndarray, texel_px: np.ndarray, quality: np.ndarray,
                keep_mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """What a frame shows of the atlas: (colours (S, S, 3) float32 sampled bilinearly from
        ``frame`` (H, W, 3) uint8 at ``texel_px``, quality (S, S) float32: ``quality`` with 0
        where the texel is not covered, outside the frame, or on a ``keep_mask`` (H, W) bool pixel)."""
        H, W = frame.shape[:2]
        mx = np.nan_to_num(texel_px[..., 0], nan=-10.0).astype(np.float32)
        my = np.nan_to_num(texel_px[..., 1], nan=-10.0).astype(np.float32)
        q = np.where((mx >= 0) & (my >= 0) & (mx <= W - 1) & (my <= H - 1), quality, 0.0).astype(np.float32)
        if keep_mask is not None:
            kept = cv2.remap(np.asarray(keep_mask, np.uint8), mx, my, cv2.INTER_NEAREST,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            # a hand's edge blurs into the pixels around it: one texel of margin
            q[cv2.dilate(kept, np.ones((3, 3), np.uint8)) != 0] = 0.0
        colours = cv2.remap(frame, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float32)
        return colours, q

    def estimate_gain(self, colours: np.ndarray, quality: np.ndarray, win=(slice(None), slice(None))) -> np.ndarray:
        """The per-channel gain (3,) float32 that brings ``colours`` (the atlas's ``win`` (rows, cols)
        slices: (h, w, 3)) to the atlas's
        lighting, from the texels both see well (this frame's quality and the atlas's best at
        least 0.3); the current gain when fewer than ``min_overlap`` are."""
        both = (quality >= 0.3) & (self.best[win] >= 0.3) & (self.weight[win] > 0)
        if int(both.sum()) < self.min_overlap:
            return self.gain
        seen = colours[both].astype(np.float64).sum(axis=0)
        known = self.colour[win][both].astype(np.float64).sum(axis=0)
        gain = np.where(seen > 1.0, known / np.maximum(seen, 1.0), 1.0)
        return np.clip(gain, *self.gain_limits).astype(np.float32)

    def update(self, frame: np.ndarray, texel_px: np.ndarray, quality: np.ndarray,
               keep_mask: np.ndarray | None = None) -> int:
        """Take one frame: ``frame`` (H, W, 3) uint8 BGR, ``texel_px`` (S, S, 2) and ``quality``
        (S, S) as :mod:`.atlas_raster` gives them, ``keep_mask`` (H, W) bool or None. Returns how
        many texels took the frame's colour."""
        S = self.size
        if texel_px.shape != (S, S, 2) or quality.shape != (S, S):
            raise ValueError(f"texel maps must be ({S}, {S}, 2) and ({S}, {S}), got {texel_px.shape}, {quality.shape}")
        self.best *= self.decay
        self.weight *= self.decay
        self.updates += 1
        seen = np.isfinite(texel_px[..., 0])
        if not seen.any():
            return 0
        # the work on the bounding box of the texels the frame covers
        ys, xs = np.nonzero(seen.any(axis=1))[0], np.nonzero(seen.any(axis=0))[0]
        win = (slice(ys[0], ys[-1] + 1), slice(xs[0], xs[-1] + 1))
        colours, q = self.observe(frame, texel_px[win], quality[win], keep_mask)
        colour, weight, best = self.colour[win], self.weight[win], self.best[win]
        self.gain = self.estimate_gain(colours, q, win)
        colours *= self.gain
        valid = q >= self.min_quality
        weight[valid & (q > best * self.replace_ratio)] = 0.0   # much better than the best: replaces
        take = valid & (q >= best * self.keep_ratio)
        beta = np.where(take, q / np.maximum(weight + q, 1e-6), 0.0).astype(np.float32)
        colour += beta[..., None] * (colours - colour)
        np.copyto(weight, np.minimum(weight + q, self.max_weight), where=take)
        np.maximum(best, np.where(take, q, 0.0), out=best)
        return int(take.sum())

    def confidence(self) -> np.ndarray:
        """(S, S) float32 in [0, 1]: how well each texel is known: 0 up to a best quality of
        CONFIDENT[0] (a texel only ever seen obliquely, where a fit that is off by a pixel or two
        samples the wrong surface), rising to 1 at CONFIDENT[1]."""
        lo, hi = CONFIDENT
        return np.where(self.weight > 0, np.clip((self.best - lo) / (hi - lo), 0.0, 1.0), 0.0).astype(np.float32)

    def image(self, lighting: str = "atlas") -> np.ndarray:
        """(S, S, 3) uint8 BGR: the atlas in its own lighting ("atlas") or in the last frame's
        ("frame": divided by the gain). Texels never seen are black."""
        if lighting not in ("atlas", "frame"):
            raise ValueError(f"lighting must be 'atlas' or 'frame', got {lighting!r}")
        img = self.colour if lighting == "atlas" else self.colour / self.gain
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def sample(self, uv: np.ndarray, lighting: str = "frame") -> tuple[np.ndarray, np.ndarray]:
        """The atlas at texture coordinates ``uv`` (..., 2) float32 in [0, 1], bilinear: (colours
        (..., 3) float32 BGR, confidence (...) float32)."""
        uv = np.asarray(uv, np.float32)
        shape = uv.shape[:-1]
        n = int(np.prod(shape))
        rows = -(-n // 1024)   # cv2.remap takes fewer than 32767 rows: lay the points out 1024 a row
        grid = np.zeros((rows * 1024, 2), np.float32)
        grid[:n] = uv.reshape(-1, 2) * self.size - 0.5
        grid = grid.reshape(rows, 1024, 2)
        col = cv2.remap(self.colour, grid[..., 0], grid[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if lighting == "frame":   # the gain is per channel: dividing the samples is dividing the atlas
            col /= self.gain
        conf = cv2.remap(self.confidence(), grid[..., 0], grid[..., 1], cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return col.reshape(-1, 3)[:n].reshape(*shape, 3), conf.reshape(-1)[:n].reshape(shape)


def blend_atlas(warped: np.ndarray, offsets: np.ndarray, extra: np.ndarray, changed: np.ndarray,
                atlas: TextureAtlas) -> np.ndarray:
    """Blend ``atlas`` into ``warped`` ((h, w, 3) uint8, the frame sampled through the source map;
    in place) where the input sees the ``changed`` ((h, w) bool) pixels' surface badly: the source
    map's stretch (linear, from the Jacobian of ``offsets`` (h, w, 2) px) over ATLAS_STRETCH, or
    the input-view frontality (``extra[..., 2]``) under ATLAS_GRAZING; weighted by the atlas's
    confidence at the pixels' texture coordinates (``extra[..., :2]``: the source map's extras,
    (h, w, >= 3) float32). Returns the (h, w) float32 weight the atlas got."""
    # float64: the offsets of uncovered pixels are huge, and float32 differences of them cancel
    gy, gx = np.gradient(np.asarray(offsets, np.float64), axis=(0, 1))
    det = (1.0 + gx[..., 0]) * (1.0 + gy[..., 1]) - gy[..., 0] * gx[..., 1]
    lo, hi = ATLAS_STRETCH
    front = extra[..., 2]
    # the atlas's pixels: stretched past lo (|det| under 1 / lo^2) or grazing; only they are weighed
    ys, xs = np.nonzero(changed & ((np.abs(det) < 1.0 / lo ** 2) | (front < ATLAS_GRAZING)))
    out = np.zeros(changed.shape, np.float32)
    if not len(ys):
        return out
    stretch = 1.0 / np.sqrt(np.maximum(np.abs(det[ys, xs]), 1e-6))
    w = np.maximum(np.clip((stretch - lo) / (hi - lo), 0.0, 1.0), np.clip(1.0 - front[ys, xs] / ATLAS_GRAZING, 0.0, 1.0))
    colours, confidence = atlas.sample(np.clip(extra[ys, xs, :2], 0.0, 1.0))
    w = (w * confidence).astype(np.float32)
    mixed = warped[ys, xs].astype(np.float32) * (1.0 - w[:, None]) + colours * w[:, None]
    on = w > 0
    warped[ys[on], xs[on]] = np.clip(np.rint(mixed[on]), 0, 255).astype(np.uint8)
    out[ys, xs] = w
    return out
