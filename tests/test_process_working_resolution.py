"""Landmarks at a working resolution: a large frame is halved (exact 2 x 2 means) to at most a
pixel budget, tracked there, and the points carried back; on a real face video upscaled to 2048 px
the points stay within a small share of the inter-ocular distance of those found on the full frame."""

from __future__ import annotations

import cv2
import numpy as np

from facesculpt.geometry.halving import frame_intrinsics, halve, halved_intrinsics, halvings
from facesculpt.nodes.landmarks import LandmarkDetector
from facesculpt.nodes.landmarks.detector import Face
from facesculpt.nodes.landmarks.working_resolution import to_full_resolution, track_at_working_resolution


def test_halvings_and_exact_halves():
    assert halvings(3840, 2160, 1920 * 1080) == 1
    assert halvings(7680, 4320, 1920 * 1080) == 2
    assert halvings(1920, 1080, 1920 * 1080) == 0 and halvings(3840, 2160, 0) == 0
    image = np.random.default_rng(1).integers(0, 256, (7, 9, 3), np.uint8)
    half = halve(image, 1)
    blocks = image[:6, :8].astype(np.float64).reshape(3, 2, 4, 2, 3).mean(axis=(1, 3))
    assert half.shape == (3, 4, 3) and np.abs(half - blocks).max() <= 0.5


def test_points_carried_back_to_the_frame():
    points = np.array([[0.0, 0.0, 1.0], [10.5, 3.0, -2.0]], np.float32)
    face = Face(points=points, score=0.9, roi=np.array([4.5, 2.5, 20.0, 20.0, 0.3], np.float32), track_id=2)
    (back,) = to_full_resolution([face], 2)
    # pixel i of the quarter copy covers pixels 4i..4i+3 of the frame: its centre is 4i + 1.5
    np.testing.assert_allclose(back.points, [[1.5, 1.5, 4.0], [43.5, 13.5, -8.0]])
    np.testing.assert_allclose(back.roi, [19.5, 11.5, 80.0, 80.0, 0.3])
    assert back.track_id == 2 and back.score == 0.9 and face.points[1, 0] == 10.5


def test_intrinsics_of_a_halved_copy_project_where_its_pixels_are():
    K = np.array([[1000.0, 0.0, 959.5], [0.0, 1000.0, 539.5], [0.0, 0.0, 1.0]])
    point = np.array([0.1, -0.05, 1.0])
    x_frame = (K @ point)[:2]
    for times in (1, 2):
        x_copy = (halved_intrinsics(K, times) @ point)[:2]
        s = 2.0 ** times  # the copy's pixel x covers frame pixels s*x .. s*x + s - 1: centre s*x + (s-1)/2
        np.testing.assert_allclose(x_copy * s + (s - 1) / 2, x_frame)
        np.testing.assert_allclose(frame_intrinsics(halved_intrinsics(K, times), times), K)


def test_working_resolution_landmarks_match_full_resolution(data_dir, models_dir):
    cv2.setNumThreads(1)
    full, work = LandmarkDetector(models_dir=models_dir), LandmarkDetector(models_dir=models_dir)
    cap = cv2.VideoCapture(str(data_dir / "video" / "d3.mp4"))
    errors = []
    for _ in range(12):
        ok, frame = cap.read()
        assert ok
        big = cv2.resize(frame, (2048, 2048), interpolation=cv2.INTER_CUBIC)  # 4.2 MP: halved once
        a, b = full.track(big), track_at_working_resolution(work, big, 1920 * 1080)
        assert len(a) == len(b) == 1
        iod = np.linalg.norm(a[0].points[33, :2] - a[0].points[263, :2])
        errors.append(np.linalg.norm(a[0].points[:, :2] - b[0].points[:, :2], axis=1).mean() / iod)
        np.testing.assert_allclose(a[0].roi[2], b[0].roi[2], rtol=0.03)
    cap.release()
    print(f"\nmean point distance, working vs full resolution: {100 * np.mean(errors):.3f} % IOD (max {100 * max(errors):.3f} %)")
    assert np.mean(errors) < 0.004 and max(errors) < 0.008, errors  # under 0.4 % (0.8 %) of the IOD
