"""Box overlap and mediapipe's weighted non-maximum suppression of SSD detections (the face
detector and the palm detector share them)."""

from __future__ import annotations

import numpy as np


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
