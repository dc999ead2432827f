"""Tracking on every shared video: a face in >= 99 % of frames, the detector rarely rerun,
landmark jitter of the nose bridge after removing the head's median motion."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facesculpt.nodes.landmarks import LandmarkDetector
from facesculpt.nodes.landmarks.detector import LEFT_EYE_OUTER, RIGHT_EYE_OUTER

NOSE_BRIDGE = 168  # mesh point between the eyes (iBUG 28, 1-based)


def _frames(path):
    cap = cv2.VideoCapture(str(path))
    while True:
        ok, frame = cap.read()
        if not ok:
            return
        yield frame


@pytest.mark.parametrize("video", ["d0", "d3", "d12", "s18"])
def test_tracking_finds_the_face_in_nearly_every_frame(models_dir, data_dir, video):
    detector = LandmarkDetector(models_dir)
    frames = found = detector_runs = 0
    previous, jitter, eye_distance = None, [], []
    for frame in _frames(data_dir / "video" / f"{video}.mp4"):
        faces = detector.track(frame)
        frames += 1
        detector_runs += detector.last_ran_detector
        if not faces:
            previous = None
            continue
        found += 1
        points = faces[0].points[:, :2].astype(np.float64)
        assert faces[0].points.shape == (468, 3) and faces[0].points.dtype == np.float32
        eye_distance.append(np.linalg.norm(points[LEFT_EYE_OUTER] - points[RIGHT_EYE_OUTER]))
        if previous is not None:
            motion = points - previous
            jitter.append(np.linalg.norm(motion[NOSE_BRIDGE] - np.median(motion, axis=0)))
        previous = points
    jitter = np.array(jitter)
    print(f"{video}: {frames} frames, face in {found / frames:.1%}, detector ran {detector_runs}x, "
          f"nose-bridge jitter mean {jitter.mean():.3f} px, median {np.median(jitter):.3f} px, "
          f"p95 {np.percentile(jitter, 95):.3f} px (eye distance {np.mean(eye_distance):.0f} px)")
    assert frames > 50
    assert found >= 0.99 * frames
    assert detector_runs <= max(2, 0.05 * frames)  # tracking, not detecting every frame
    assert np.median(jitter) < 0.02 * np.mean(eye_distance)


def test_track_reuses_the_last_crop_and_detect_always_detects(models_dir, data_dir):
    frames = list(_frames(data_dir / "video" / "d0.mp4"))[:5]
    detector = LandmarkDetector(models_dir)
    detector.track(frames[0])
    assert detector.last_ran_detector
    for frame in frames[1:]:
        faces = detector.track(frame)
        assert faces and not detector.last_ran_detector
    detector.detect(frames[-1])
    assert detector.last_ran_detector
    detector.reset()
    detector.track(frames[-1])
    assert detector.last_ran_detector


def test_a_lost_face_brings_the_detector_back(models_dir, data_dir):
    frames = list(_frames(data_dir / "video" / "d3.mp4"))[:3]
    detector = LandmarkDetector(models_dir)
    assert detector.track(frames[0])
    blank = np.full_like(frames[0], 127)
    assert detector.track(blank) == []
    assert detector.last_ran_detector
    faces = detector.track(frames[1])
    assert faces and detector.last_ran_detector


def test_several_faces_are_tracked_without_rerunning_the_detector(models_dir, data_dir):
    image = cv2.imread(str(data_dir / "faces" / "2008_002506.jpg"))  # three faces, 90-110 px
    detector = LandmarkDetector(models_dir, max_faces=3)
    first = detector.track(image)
    assert len(first) == 3 and detector.last_ran_detector
    for _ in range(5):
        faces = detector.track(image)
        assert len(faces) == 3 and not detector.last_ran_detector
    # Still image: every track stays on its own face.
    for a, b in zip(first, faces):
        assert np.abs(a.points[:, :2] - b.points[:, :2]).mean() < 2.0


def test_a_large_crop_is_area_downsampled_on_whole_pixels_and_lands_where_its_roi_says():
    """crop_image shrinks a large ROI by a whole factor first (its part of the image grown to a
    multiple of the factor, OpenCV's fast path): the crop must still show exactly the ROI."""
    import cv2

    from facesculpt.geometry.crops import _multiple_span, crop_image

    assert _multiple_span(10, 17, 100, 3) == (10, 19) and _multiple_span(90, 99, 100, 4) == (88, 100)
    assert _multiple_span(0, 5, 5, 2) == (0, 4)  # the image ends: trimmed to a multiple
    h, w = 1080, 1920
    ys, xs = np.mgrid[:h, :w].astype(np.float32)
    image = np.dstack([xs / 4 % 256, ys / 4 % 256, np.zeros_like(xs)]).astype(np.uint8)  # position-coded
    for roi in ([963.4, 541.7, 701.0, 701.0, 0.0], [420.2, 300.9, 500.0, 500.0, 0.3], [1800.0, 1000.0, 600.0, 600.0, 0.0]):
        crop = crop_image(image, np.array(roi), 192)
        # the centre pixel of the crop is the ROI's centre in the image
        cx, cy = crop[96, 96, 0] * 4.0, crop[96, 96, 1] * 4.0
        assert abs(cx - roi[0] % 1024) < 12 and abs(cy - roi[1] % 1024) < 12, (roi, cx, cy)
        # and the crop equals a direct warp of the area-smoothed image closely (no shift)
        f = int(max(roi[2], roi[3]) / 192)
        ref = cv2.warpAffine(cv2.blur(image, (f, f)), _matrix(roi), (192, 192),
                             flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
        inside = (slice(20, 172), slice(20, 172))
        assert np.median(np.abs(crop[inside].astype(int) - ref[inside].astype(int))) <= 1


def _matrix(roi):
    from facesculpt.geometry.crops import crop_matrix

    return crop_matrix(np.array(roi), 192)
