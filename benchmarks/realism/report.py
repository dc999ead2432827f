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
    """results[edit][method] = {"psnr", "ssim", "sharpness", "seam", "landing": {...}, "lips_px"}."""
    lines = ["| edit | method | PSNR dB | SSIM | sharpness | seam | landing error % | reach | lower lip moved px |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for edit, methods in results.items():
        for method, r in methods.items():
            if "error" in r:
                lines.append(f"| {edit} | {method} | failed: {r['error'][:200]} | | | | | | |")
                continue
            if "psnr" not in r:
                if "lips_px" in r:
                    lines.append(f"| {edit} | {method} | – | – | – | – | – | – | {_f(r['lips_px'], '{:.1f}')} |")
                continue
            land = r.get("landing", {}).get("all", {})
            lines.append(f"| {edit} | {method} | {_f(r['psnr'])} | {_f(r['ssim'], '{:.3f}')} | "
                         f"{_f(r['sharpness'])} | {_f(r['seam'])} | {_f(land.get('error_pct'), '{:.0f}')} | "
                         f"{_f(land.get('reach'))} | {_f(r.get('lips_px'), '{:.1f}')} |")
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


def crop_boxes(gts: list, inputs: list, size: tuple[int, int], pad: int = 18, min_side: int = 110) -> list:
    """One box (x0, y0, x1, y1) per frame around its edit region, all of one size (the largest
    region's, with ``pad`` px around it, at least ``min_side``), kept inside the image."""
    W, H = size
    regions = [edit_region(g, i) for g, i in zip(gts, inputs)]
    spans, centres = [], []
    for m in regions:
        if not m.any():
            spans.append(min_side)
            centres.append((W / 2, H / 2))
            continue
        ys, xs = np.nonzero(m)
        spans.append(max(xs.max() - xs.min(), ys.max() - ys.min()))
        centres.append(((xs.min() + xs.max()) / 2, (ys.min() + ys.max()) / 2))
    side = int(min(max(max(spans), min_side) + 2 * pad, W, H))
    boxes = []
    for cx, cy in centres:
        x0 = int(np.clip(cx - side / 2, 0, W - side))
        y0 = int(np.clip(cy - side / 2, 0, H - side))
        boxes.append((x0, y0, x0 + side, y0 + side))
    return boxes


def side_by_side(panels: list[list[tuple[str, np.ndarray]]], boxes: list, zoom: int = 2) -> np.ndarray:
    """Rows of labelled panels (label, full frame), each row cropped to its box of ``boxes``
    (all of one size) and enlarged ``zoom`` times (nearest neighbour: every pixel shows)."""
    rows = []
    for row, (x0, y0, x1, y1) in zip(panels, boxes):
        cells = []
        for label, img in row:
            c = cv2.resize(img[y0:y1, x0:x1], None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)
            cells.append(_label(c, label))
            cells.append(np.full((cells[-1].shape[0], 4, 3), 255, np.uint8))
        rows.append(np.hstack(cells[:-1]))
        rows.append(np.full((4, rows[-1].shape[1], 3), 255, np.uint8))
    return np.vstack(rows[:-1])
