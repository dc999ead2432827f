"""Scores of one method (a sequence of frames) against the ground truth, and of a processed
real video against its input (no ground truth). See :mod:`.metrics` for the definitions."""

from __future__ import annotations

import cv2
import numpy as np

from .metrics import (
    Pooled,
    changed,
    edit_region,
    gradient_magnitude,
    laplacian_variance,
    psnr_from_mse,
    seam_band,
    squared_error,
    ssim_map,
)

#: Yaw bins (degrees) of the handle-landing figure.
YAW_BINS = [(-25.5, -15.0), (-15.0, -5.0), (-5.0, 5.0), (5.0, 15.0), (15.0, 25.5)]
#: Closing (px) of a result's changed region before its boundary is taken (fills speckle).
CLOSE_PX = 4
#: Image displacements (px) below this are too small to score a handle's landing.
MIN_HANDLE_PX = 1.5


def changed_region(result: np.ndarray, inp: np.ndarray) -> np.ndarray:
    """(H, W) bool: where ``result`` differs from the input, closed and with holes filled."""
    m = changed(result, inp).astype(np.uint8)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * CLOSE_PX + 1, 2 * CLOSE_PX + 1))
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, k)
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    filled = np.zeros_like(m)
    cv2.drawContours(filled, contours, -1, 1, thickness=cv2.FILLED)
    return filled.astype(bool)


def score_frame(pool: Pooled, result: np.ndarray, gt: np.ndarray, inp: np.ndarray) -> None:
    """Add one frame of a method's ``result`` against the ground truth ``gt`` to ``pool``:
    squared error and SSIM over the edit region, Laplacian variances, seam gradients."""
    region = edit_region(gt, inp)
    if not region.any():
        return
    se, n = squared_error(result, gt, region)
    pool.add("se", se, n)
    pool.add("ssim", float(ssim_map(result, gt)[region].sum()), int(region.sum()))
    pool.add("lap_result", laplacian_variance(result, region), 1)
    pool.add("lap_truth", laplacian_variance(gt, region), 1)
    if changed(result, inp).any():
        band = seam_band(changed_region(result, inp))
        pool.add("grad_result", float(gradient_magnitude(result)[band].sum()), int(band.sum()))
        pool.add("grad_truth", float(gradient_magnitude(gt)[band].sum()), int(band.sum()))


def summarise(pool: Pooled) -> dict:
    """PSNR (dB), SSIM, sharpness ratio, seam ratio from a pooled score (NaN where undefined)."""
    def ratio(a, b):
        return pool.mean(a) / pool.mean(b) if pool.count.get(a) and pool.count.get(b) else float("nan")

    return {"psnr": psnr_from_mse(pool.mean("se")) if pool.count.get("se") else float("nan"),
            "ssim": pool.mean("ssim"), "sharpness": ratio("lap_result", "lap_truth"),
            "seam": ratio("grad_result", "grad_truth"), "frames": int(pool.count.get("lap_truth", 0))}


def landing(measured: float, reference: float, true_px: float) -> tuple[float, float] | None:
    """(error %, reach) of one handle in one frame: reach = ``measured`` / ``reference``, the
    distance (px) the face around the handle moved along the true displacement in a result over
    the same measurement on the ground truth (or over the true displacement ``true_px`` itself,
    for the measurement check); error = |1 - reach| in %. None when the true displacement is
    under :data:`MIN_HANDLE_PX` or the reference under a third of it."""
    if true_px < MIN_HANDLE_PX or abs(reference) < true_px / 3:
        return None
    reach = float(measured) / float(reference)
    return abs(1.0 - reach) * 100.0, reach


def landing_by_yaw(samples: list[tuple[float, float, float]]) -> dict:
    """Median error % and median reach per yaw bin (and 'all') of samples (yaw, error %, reach)."""
    out = {}
    a = np.array(samples, np.float64).reshape(-1, 3)
    for lo, hi in [*YAW_BINS, (-90.0, 90.0)]:
        m = (a[:, 0] >= lo) & (a[:, 0] < hi)
        key = "all" if hi - lo > 60 else f"{lo:+.0f}..{hi:+.0f}"
        out[key] = ({"error_pct": float(np.median(a[m, 1])), "reach": float(np.median(a[m, 2])), "n": int(m.sum())}
                    if m.any() else {"error_pct": float("nan"), "reach": float("nan"), "n": 0})
    return out


def score_real_frame(pool: Pooled, result: np.ndarray, inp: np.ndarray) -> None:
    """Add one frame of a processed real video to ``pool``: Laplacian variance of the result and
    of the input over the re-rendered region (shrunk by the seam band), gradients on its seam."""
    region = changed_region(result, inp)
    if region.sum() < 50:
        return
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))
    inner = cv2.erode(region.astype(np.uint8), k).astype(bool)
    if inner.sum() >= 50:
        pool.add("lap_result", laplacian_variance(result, inner), 1)
        pool.add("lap_truth", laplacian_variance(inp, inner), 1)
    band = seam_band(region)
    pool.add("grad_result", float(gradient_magnitude(result)[band].sum()), int(band.sum()))
    pool.add("grad_truth", float(gradient_magnitude(inp)[band].sum()), int(band.sum()))
    pool.add("area", float(region.sum()), 1)
