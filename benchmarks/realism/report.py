"""The benchmark's outputs: markdown tables and side-by-side crops."""

from __future__ import annotations

import math

import cv2
import numpy as np

from .metrics import edit_region
from .scoring import YAW_BINS


def _f(x, fmt="{:.2f}") -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    if isinstance(x, float) and math.isinf(x):
        return "inf"
    return fmt.format(x)


def synthetic_table(results: dict) -> str:
    """results[edit][method] = {"psnr", "ssim", "sharpness", "seam", "landing": {...}}."""
    lines = ["| edit | method | PSNR dB | SSIM | sharpness | seam | landing error % | reach |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for edit, methods in results.items():
        for method, r in methods.items():
            if "error" in r:
                lines.append(f"| {edit} | {method} | failed: {r['error'][:200]} | | | | | |")
                continue
            if "psnr" not in r:
                continue
            land = r.get("landing", {}).get("all", {})
            lines.append(f"| {edit} | {method} | {_f(r['psnr'])} | {_f(r['ssim'], '{:.3f}')} | "
                         f"{_f(r['sharpness'])} | {_f(r['seam'])} | {_f(land.get('error_pct'), '{:.0f}')} | "
                         f"{_f(land.get('reach'))} |")
    return "\n".join(lines)


def landing_table(results: dict) -> str:
    """Handle landing per yaw bin: median error % (reach) for every method that has it."""
    keys = [f"{lo:+.0f}..{hi:+.0f}" for lo, hi in YAW_BINS] + ["all"]
    lines = ["| edit | method | " + " | ".join(f"yaw {k}" if k != "all" else "all" for k in keys) + " |",
             "| --- | --- |" + " ---: |" * len(keys)]
    for edit, methods in results.items():
        for method, r in methods.items():
            if "landing" not in r or method == "do nothing":
                continue
            cells = [f"{_f(r['landing'][k]['error_pct'], '{:.0f}')} % ({_f(r['landing'][k]['reach'])})" for k in keys]
            lines.append(f"| {edit} | {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def real_table(rows: list[dict]) -> str:
    lines = ["| video | model | edit | sharpness (result / input) | seam (result / input) | re-rendered px | frames |",
             "| --- | --- | --- | ---: | ---: | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {r['video']} | {r['model']} | {r['edit']} | {_f(r['sharpness'])} | {_f(r['seam'])} | "
                     f"{_f(r['area'], '{:.0f}')} | {r['frames']} |")
    return "\n".join(lines)


def _label(img: np.ndarray, text: str) -> np.ndarray:
    strip = np.full((22, img.shape[1], 3), 255, np.uint8)
    cv2.putText(strip, text, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([strip, img])


def crop_box(gts: list, inputs: list, size: tuple[int, int], pad: int = 18, min_side: int = 110):
    """A box (x0, y0, x1, y1) around the edit regions of the given ground-truth frames."""
    m = np.zeros(gts[0].shape[:2], bool)
    for g, i in zip(gts, inputs):
        m |= edit_region(g, i)
    W, H = size
    if not m.any():
        return 0, 0, W, H
    ys, xs = np.nonzero(m)
    cx, cy = (xs.min() + xs.max()) / 2, (ys.min() + ys.max()) / 2
    half = max(xs.max() - xs.min(), ys.max() - ys.min(), min_side) / 2 + pad
    x0, y0 = int(max(cx - half, 0)), int(max(cy - half, 0))
    return x0, y0, int(min(x0 + 2 * half, W)), int(min(y0 + 2 * half, H))


def side_by_side(panels: list[list[tuple[str, np.ndarray]]], box, zoom: int = 2) -> np.ndarray:
    """Rows of labelled panels (label, full frame), each cropped to ``box`` and enlarged
    ``zoom`` times (nearest neighbour: every pixel shows)."""
    x0, y0, x1, y1 = box
    rows = []
    for row in panels:
        cells = []
        for label, img in row:
            c = cv2.resize(img[y0:y1, x0:x1], None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)
            cells.append(_label(c, label))
            cells.append(np.full((cells[-1].shape[0], 4, 3), 255, np.uint8))
        rows.append(np.hstack(cells[:-1]))
        rows.append(np.full((4, rows[-1].shape[1], 3), 255, np.uint8))
    return np.vstack(rows[:-1])
