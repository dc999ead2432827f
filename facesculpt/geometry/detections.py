"""SSD detections as mediapipe's detectors give them: anchor centres, decoding of the raw
outputs, box overlap and weighted non-maximum suppression (the face detector and the palm
detector share them; each passes its own input size, strides and keypoint count)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class Detection:
    """A detector result in image pixels (continuous coordinates): ``box`` (4,) float32
    [xmin, ymin, xmax, ymax], ``keypoints`` (K, 2) float32, ``score`` in [0, 1]."""

    box: np.ndarray
    keypoints: np.ndarray
    score: float


def ssd_anchors(size: int, strides) -> np.ndarray:
    """Anchor centres (A, 2) float32, normalised [0, 1], of an SSD on a ``size`` x ``size`` input.

    Layers with the same stride share one grid; each layer puts two anchors per cell (aspect
    ratio 1 and the interpolated scale), row by row; with fixed anchor size every anchor is 1x1.
    """
    centres = []
    i = 0
    while i < len(strides):
        stride = strides[i]
        per_cell = 0
        while i < len(strides) and strides[i] == stride:
            per_cell += 2
            i += 1
        grid = int(math.ceil(size / stride))
        ys, xs = np.meshgrid(np.arange(grid), np.arange(grid), indexing="ij")
        cell = np.stack([(xs + 0.5) / grid, (ys + 0.5) / grid], axis=-1).reshape(-1, 1, 2)
        centres.append(np.repeat(cell, per_cell, axis=1).reshape(-1, 2))
    return np.concatenate(centres).astype(np.float32)


def decode_ssd(raw_boxes: np.ndarray, raw_scores: np.ndarray, anchors: np.ndarray, size: int,
               num_keypoints: int, min_score: float = 0.5):
    """Decode an SSD's raw outputs. raw_boxes (A, 4 + 2 K) float32: per anchor dx, dy, w, h, then
    K (x, y) keypoints, in input pixels relative to the anchor centre; raw_scores (A,) logits.
    Returns normalised ``boxes`` (N, 4) [xmin, ymin, xmax, ymax], ``keypoints`` (N, K, 2) and
    ``scores`` (N,) float32 for the anchors whose sigmoid score is at least ``min_score``."""
    scores = 1.0 / (1.0 + np.exp(-np.clip(raw_scores.astype(np.float64), -100.0, 100.0)))
    keep = np.flatnonzero(scores >= min_score)
    raw = raw_boxes[keep].astype(np.float64) / size
    centre = anchors[keep].astype(np.float64)
    cxcy = raw[:, 0:2] + centre
    half = raw[:, 2:4] / 2.0
    boxes = np.concatenate([cxcy - half, cxcy + half], axis=1)
    keypoints = raw[:, 4:4 + 2 * num_keypoints].reshape(-1, num_keypoints, 2) + centre[:, None, :]
    return boxes.astype(np.float32), keypoints.astype(np.float32), scores[keep].astype(np.float32)


def box_iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Intersection over union of one box (4,) with boxes (N, 4), [xmin, ymin, xmax, ymax]."""
    lo = np.maximum(box[:2], boxes[:, :2])
    hi = np.minimum(box[2:], boxes[:, 2:])
    inter = np.prod(np.clip(hi - lo, 0.0, None), axis=1)
    area = np.prod(box[2:] - box[:2])
    areas = np.prod(boxes[:, 2:] - boxes[:, :2], axis=1)
    return inter / np.maximum(area + areas - inter, 1e-12)


def weighted_nms(boxes: np.ndarray, keypoints: np.ndarray, scores: np.ndarray,
                 iou_threshold: float = 0.3) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """mediapipe's weighted non-maximum suppression.

    Repeatedly take the highest-scoring remaining box, gather every remaining box overlapping
    it by IoU > ``iou_threshold``, and output the score-weighted mean box and keypoints of that
    cluster with the top score. Input boxes (N, 4), keypoints (N, K, 2), scores (N,). Returns
    (box (4,) float32, keypoints (K, 2) float32, score) per cluster, best first.
    """
    order = np.argsort(-scores, kind="stable")
    boxes, keypoints, scores = boxes[order], keypoints[order], scores[order]
    remaining = np.ones(len(scores), bool)
    out = []
    for i in range(len(scores)):
        if not remaining[i]:
            continue
        cluster = np.flatnonzero(remaining & (box_iou(boxes[i], boxes) > iou_threshold))
        cluster = np.union1d(cluster, [i])
        remaining[cluster] = False
        w = scores[cluster].astype(np.float64)
        w /= w.sum()
        out.append(((boxes[cluster] * w[:, None]).sum(0).astype(np.float32),
                    (keypoints[cluster] * w[:, None, None]).sum(0).astype(np.float32), float(scores[i])))
    return out


def detections_in_image(boxes: np.ndarray, keypoints: np.ndarray, scores: np.ndarray, x0: float, y0: float,
                        side: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Decoded detections of a square input (normalised boxes (N, 4), keypoints (N, K, 2), scores
    (N,), as :func:`decode_ssd` gives them) in the pixels of the image that input showed: the
    square of ``side`` pixels whose top-left corner is (``x0``, ``y0``)."""
    return (boxes * side + np.array([x0, y0, x0, y0], np.float32),
            keypoints * side + np.array([x0, y0], np.float32), scores)


def merged_detections(boxes: np.ndarray, keypoints: np.ndarray, scores: np.ndarray,
                      iou_threshold: float = 0.3) -> list[Detection]:
    """:func:`weighted_nms` of detections in image pixels as :class:`Detection` objects, best first."""
    return [Detection(box=b, keypoints=k, score=sc) for b, k, sc in weighted_nms(boxes, keypoints, scores,
                                                                                 iou_threshold)]
