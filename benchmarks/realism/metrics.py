"""The benchmark's figures on (H, W, 3) uint8 BGR frames, and the 2D liquify baseline.

* edit region: where the ground truth differs from the input (any channel by more than
  ``CHANGE_LEVEL``), dilated by ``REGION_DILATE_PX``;
* PSNR (dB) and SSIM (Gaussian window, sigma 1.5, per channel, averaged) over the edit region;
* sharpness: variance of the Laplacian of the grey image over a region;
* seam: mean gradient magnitude (Sobel) over a band of ``SEAM_BAND_PX`` px around the boundary
  of the region a result changed (where it differs from the input);
* liquify: the input warped by a dense 2D displacement field (normalised Gaussian splatting of
  per-vertex image displacements) with ``cv2.remap``: what a 2D face-reshape filter does at best;
* handle landing: how far the face around a handle moved along the handle's true image
  displacement in a result (masked patch matching from the input, :func:`shift_along`),
  against the same measurement on the ground truth.

Every figure returns the sums it is made of (:class:`Pooled`) so that frames pool exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

#: A pixel changed when some channel differs by more than this (0..255).
CHANGE_LEVEL = 2
#: Dilation (px) of the changed region into the edit region.
REGION_DILATE_PX = 4
#: Half-width (px) of the band around a changed region's boundary for the seam figure.
SEAM_BAND_PX = 1
#: Gaussian sigma (px) and density fade of the liquify field.
LIQUIFY_SIGMA_PX = 5.0


def _disk(r: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


def changed(a: np.ndarray, b: np.ndarray, level: int = CHANGE_LEVEL) -> np.ndarray:
    """(H, W) bool: pixels where some channel of a and b differs by more than ``level``."""
    return np.abs(a.astype(np.int16) - b.astype(np.int16)).max(axis=2) > level


def edit_region(gt: np.ndarray, inp: np.ndarray, dilate_px: int = REGION_DILATE_PX) -> np.ndarray:
    """(H, W) bool: where the ground truth differs from the input, dilated."""
    m = changed(gt, inp).astype(np.uint8)
    return cv2.dilate(m, _disk(dilate_px)).astype(bool)


def grey(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(np.float64)


@dataclass
class Pooled:
    """Sums over frames: ``total`` and ``count`` per named quantity."""

    total: dict[str, float] = field(default_factory=dict)
    count: dict[str, float] = field(default_factory=dict)

    def add(self, name: str, total: float, count: float) -> None:
        self.total[name] = self.total.get(name, 0.0) + float(total)
        self.count[name] = self.count.get(name, 0.0) + float(count)

    def mean(self, name: str) -> float:
        c = self.count.get(name, 0.0)
        return self.total[name] / c if c else float("nan")


def squared_error(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> tuple[float, int]:
    """(sum of squared differences, number of values) over ``mask`` (all channels)."""
    d = a[mask].astype(np.float64) - b[mask].astype(np.float64)
    return float((d * d).sum()), int(d.size)


def psnr_from_mse(mse: float) -> float:
    return float("inf") if mse <= 0 else float(10 * np.log10(255.0 ** 2 / mse))


def ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(H, W) SSIM of a and b (Wang et al. 2004: Gaussian window sigma 1.5, K1 0.01, K2 0.03,
    L 255), averaged over the channels."""
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    out = np.zeros(a.shape[:2])
    for ch in range(a.shape[2]):
        x, y = a[..., ch].astype(np.float64), b[..., ch].astype(np.float64)

        def blur(z):
            return cv2.GaussianBlur(z, (11, 11), 1.5)

        mx, my = blur(x), blur(y)
        sxx, syy, sxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
        out += ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return out / a.shape[2]


def laplacian_variance(img: np.ndarray, mask: np.ndarray) -> float:
    """Variance of the Laplacian (3x3) of the grey image over ``mask``."""
    lap = cv2.Laplacian(grey(img), cv2.CV_64F)
    return float(lap[mask].var()) if mask.any() else float("nan")


def gradient_magnitude(img: np.ndarray) -> np.ndarray:
    g = grey(img)
    return np.hypot(cv2.Sobel(g, cv2.CV_64F, 1, 0), cv2.Sobel(g, cv2.CV_64F, 0, 1))


def seam_band(region: np.ndarray, half_width: int = SEAM_BAND_PX) -> np.ndarray:
    """(H, W) bool: pixels within ``half_width`` px of the boundary of ``region``."""
    m = region.astype(np.uint8)
    edge = m - cv2.erode(m, _disk(1))
    return cv2.dilate(edge, _disk(half_width)).astype(bool)


def liquify_field(p0: np.ndarray, p1: np.ndarray, size: tuple[int, int],
                  sigma: float = LIQUIFY_SIGMA_PX) -> np.ndarray:
    """The backward displacement field (H, W, 2) px of a 2D warp that takes each visible
    vertex's image position p0 (N, 2) to p1 (N, 2): the displacements p1 - p0, splatted at p1
    (bilinear), spread by a Gaussian (``sigma`` px) and normalised by the splatted density,
    faded to zero where the density falls (beyond the face, over about ``sigma``)."""
    W, H = size
    num = np.zeros((H, W, 2))
    den = np.zeros((H, W))
    d = p1 - p0
    q = p1 - 0.5  # pixel-centre coordinates
    i0 = np.floor(q).astype(int)
    f = q - i0
    for dx in (0, 1):
        for dy in (0, 1):
            w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1])
            x, y = i0[:, 0] + dx, i0[:, 1] + dy
            ok = (x >= 0) & (x < W) & (y >= 0) & (y < H)
            np.add.at(den, (y[ok], x[ok]), w[ok])
            np.add.at(num, (y[ok], x[ok]), w[ok, None] * d[ok])
    k = int(4 * sigma) | 1
    den = cv2.GaussianBlur(den, (k, k), sigma)
    num = cv2.GaussianBlur(num, (k, k), sigma)
    inside = den[den > 0]
    ref = np.percentile(inside, 75) if inside.size else 1.0
    fade = np.clip(den / (0.5 * ref), 0.0, 1.0)
    fade = fade * fade * (3 - 2 * fade)
    return num / np.maximum(den, 1e-12)[..., None] * fade[..., None]


def liquify(img: np.ndarray, p0: np.ndarray, p1: np.ndarray, sigma: float = LIQUIFY_SIGMA_PX) -> np.ndarray:
    """``img`` warped so that content at p0 (N, 2) px lands at p1 (N, 2) (:func:`liquify_field`),
    bicubic; uint8 like ``img``."""
    H, W = img.shape[:2]
    d = liquify_field(p0, p1, (W, H), sigma)
    gx, gy = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    mx = (gx - d[..., 0]).astype(np.float32)
    my = (gy - d[..., 1]).astype(np.float32)
    return cv2.remap(img, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


def shift_along(before: np.ndarray, after: np.ndarray, point, direction, mask: np.ndarray, radius: int = 7,
                reach: float = 20.0, step: float = 0.25) -> float | None:
    """How far (px) the content of ``before`` around ``point`` (2,) px moved along ``direction``
    (2,) in ``after``: the shift t in [-reach, reach] (``step`` px apart, refined to a parabola's
    vertex) whose (2 radius + 1)² patch of ``after``, sampled at the patch's pixels + t
    direction (bilinear), differs least from ``before``'s over the pixels where ``mask`` (H, W)
    bool is set (the face: the background does not move with it). A 1D search: along a straight
    edge (a silhouette on plain skin) a 2D one cannot tell motion along the edge (the aperture
    problem). None when the patch holds too few masked pixels."""
    H, W = before.shape[:2]
    u = np.asarray(direction, np.float64)
    u = u / max(np.linalg.norm(u), 1e-12)
    cx, cy = int(np.floor(point[0])), int(np.floor(point[1]))
    ys, xs = np.mgrid[cy - radius: cy + radius + 1, cx - radius: cx + radius + 1]
    keep = (xs >= 0) & (xs < W) & (ys >= 0) & (ys < H)
    keep[keep] = mask[ys[keep], xs[keep]]
    if keep.sum() < 20:
        return None
    xs, ys = xs[keep].astype(np.float64), ys[keep].astype(np.float64)
    ref = before[ys.astype(int), xs.astype(int)].astype(np.float32)
    ts = np.arange(-reach, reach + step / 2, step)
    mx = (xs[None, :] + ts[:, None] * u[0]).astype(np.float32)
    my = (ys[None, :] + ts[:, None] * u[1]).astype(np.float32)
    got = cv2.remap(after, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float32)
    cost = ((got - ref[None]) ** 2).sum(axis=(1, 2))
    k = int(np.argmin(cost))
    if 0 < k < len(ts) - 1:
        den = cost[k - 1] - 2 * cost[k] + cost[k + 1]
        if den > 0:
            return float(ts[k] + step * 0.5 * (cost[k - 1] - cost[k + 1]) / den)
    return float(ts[k])
