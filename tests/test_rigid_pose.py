"""The rigid pose from the pixels (issue 46, item 3): the face's rigid regions leave out the mouth
and the eyes, a pose a few degrees off is pulled back by the photometric step on those regions,
and a lighting change over one region does not move the pose when each region has its own gain
and bias (benchmarks/bench_appearance.py measures it on the synthetic head and real video)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facesculpt.geometry.projection import project
from facesculpt.nodes.fitter.appearance import Refinement, pose_prior_weight, refine_pose
from facesculpt.nodes.fitter.rigid_regions import (
    FOREHEAD,
    LEFT_CHEEKBONE,
    NOSE_BRIDGE,
    RIGHT_CHEEKBONE,
    rigid_regions,
)

K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
#: Where the Surrey model's mean face has its named landmarks (mm: x to the subject's left, y up, z out).
FACE_POINTS = {"right_eye_outer": (-46, 35, -36), "left_eye_outer": (46, 35, -36), "right_eye_inner": (-19, 32, -30),
               "left_eye_inner": (19, 32, -30), "right_brow": (-30, 52, -20), "left_brow": (30, 52, -20),
               "nose_bridge": (0, 41, -17), "nose_tip": (0, -2, 3), "mouth_right": (-24, -36, -28),
               "mouth_left": (24, -36, -28)}


def _face():
    """A face-like grid (mm, model space) and its named landmarks: the grid vertex nearest each point."""
    ys, xs = np.mgrid[-80:101:4, -70:71:4].astype(float)
    z = -30 + 30 * np.exp(-(xs ** 2) / 300.0) * (ys > -10) - 0.004 * xs ** 2
    X = np.column_stack([xs.ravel(), ys.ravel(), z.ravel()])
    names = {n: int(np.argmin(np.linalg.norm(X[:, :2] - p[:2], axis=1))) for n, p in FACE_POINTS.items()}
    return X, names


def test_the_rigid_regions_are_the_forehead_the_nose_bridge_and_the_cheekbones():
    X, names = _face()
    labels = rigid_regions(X, names)
    at = {n: labels[v] for n, v in names.items()}
    assert set(np.unique(labels)) == {-1, FOREHEAD, NOSE_BRIDGE, RIGHT_CHEEKBONE, LEFT_CHEEKBONE}
    assert at["nose_bridge"] == NOSE_BRIDGE
    assert all(at[n] == -1 for n in ("mouth_right", "mouth_left", "right_eye_outer", "left_eye_inner", "nose_tip"))
    assert X[labels == FOREHEAD, 1].min() > 52 and X[labels == RIGHT_CHEEKBONE, 0].max() < 0 < \
        X[labels == LEFT_CHEEKBONE, 0].min()
    assert not (labels[np.abs(X[:, 0]) > 50] >= 0).any()           # nothing near the outline
    with pytest.raises(ValueError, match="nose_tip"):
        rigid_regions(X, {n: v for n, v in names.items() if n != "nose_tip"})


def _scene():
    """A bumpy surface 500 mm away in four regions (quadrants, a gap between them), an image whose
    grey levels are a smooth pattern, and the template: that pattern at the surface's true pixels."""
    ys, xs = np.mgrid[-60:61:5, -50:51:5].astype(float)
    X = np.column_stack([xs.ravel(), ys.ravel(), 500.0 - 8 * np.exp(-(xs ** 2 + ys ** 2).ravel() / 900.0)])
    regions = np.where(X[:, 0] > 0, 1, 0) + np.where(X[:, 1] > 0, 2, 0)
    regions[(np.abs(X[:, 0]) < 12) | (np.abs(X[:, 1]) < 12)] = -1
    gy, gx = np.mgrid[0:480, 0:640].astype(np.float32)
    image = (128 + 50 * np.sin(gx / 11.0) * np.cos(gy / 13.0) + 30 * np.sin((gx + gy) / 23.0)).astype(np.float32)
    image = cv2.GaussianBlur(image, (0, 0), 1.5)
    px = project(X, K).astype(np.float32)
    template = cv2.remap(image, px[:, 0].reshape(1, -1), px[:, 1].reshape(1, -1), cv2.INTER_LINEAR).ravel()
    return X, regions, image, template.astype(np.float64)


def test_a_pose_a_few_degrees_off_is_pulled_back_from_the_rigid_regions():
    X, regions, image, template = _scene()
    off = Refinement(np.r_[np.radians([3.0, -2.5, 1.0]), 2.0, -1.5, 0.0]).apply(X)
    before = np.linalg.norm(project(off, K) - project(X, K), axis=1).mean()
    weights = (regions >= 0).astype(float)
    found = refine_pose(image, off, weights, template, K, np.zeros(0, np.int64), levels=(0.25, 0.5, 1.0),
                        regions=regions)
    after = np.linalg.norm(project(found.apply(off), K) - project(X, K), axis=1).mean()
    assert before > 2.5 and after < 0.1 * before


def test_a_lighting_change_over_one_region_does_not_move_the_pose():
    X, regions, image, template = _scene()
    px = project(X, K)
    shaded = image.copy()
    right = int(np.round(px[regions == 1, 0].min() - 6))       # the image right of the gap: region 1 and 3
    shaded[:, right:] = 0.6 * shaded[:, right:] + 40.0
    weights = (regions >= 0).astype(float)
    moved = {}
    for name, r in (("one lighting", None), ("per region", regions)):
        found = refine_pose(shaded, X, weights, template, K, np.zeros(0, np.int64), levels=(0.5, 1.0), regions=r)
        moved[name] = np.linalg.norm(project(found.apply(X), K) - px, axis=1).mean()
    assert moved["per region"] < 0.1 and moved["per region"] < 0.25 * moved["one lighting"]


def test_the_landmark_prior_weighs_more_the_closer_the_landmarks_agree():
    weights = [pose_prior_weight(r) for r in (0.1, 1.0, 2.0, 4.0, float("nan"))]
    assert weights[0] == weights[1] >= weights[2] > weights[3] > 0 and np.isfinite(weights[4])
