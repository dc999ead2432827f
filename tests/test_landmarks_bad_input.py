"""Bad input never raises: empty, grey, tiny, huge, non-uint8 images give faces or an empty
list; a missing model directory names `facesculpt setup`."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facesculpt.nodes.landmarks import LandmarkDetector
from facesculpt.nodes.landmarks.detector import as_bgr_uint8
from facesculpt.paths import MissingModelsError


@pytest.fixture(scope="module")
def detector(models_dir):
    return LandmarkDetector(models_dir)


@pytest.fixture(scope="module")
def face(data_dir):
    cap = cv2.VideoCapture(str(data_dir / "video" / "d3.mp4"))
    ok, frame = cap.read()
    assert ok
    return frame


def _check(faces):
    assert isinstance(faces, list)
    for f in faces:
        assert f.points.shape == (468, 3) and f.points.dtype == np.float32
        assert np.all(np.isfinite(f.points)) and 0.0 <= f.score <= 1.0
        assert f.roi.shape == (5,)
    return faces


@pytest.mark.parametrize("image", [
    np.zeros((0, 0, 3), np.uint8),
    np.zeros((0, 640, 3), np.uint8),
    np.zeros((480, 640, 0), np.uint8),
    np.zeros((5,), np.uint8),
    np.zeros((4, 4, 4, 4), np.uint8),
    None,
    "not an image",
    [[1, 2], [3]],
    np.full((480, 640, 3), 128, np.uint8),      # grey
    np.full((480, 640), 128, np.uint8),         # single channel
    np.zeros((16, 16, 3), np.uint8),            # tiny
    np.random.default_rng(0).integers(0, 256, (16, 16, 3)).astype(np.uint8),
    np.full((1, 1, 3), 255, np.uint8),
    np.zeros((480, 640, 2), np.uint8),          # two channels: not an image
], ids=["empty", "zero-height", "zero-channels", "1d", "4d", "none", "string", "ragged", "grey", "grey-2d",
        "tiny-black", "tiny-noise", "one-pixel", "two-channels"])
def test_images_without_faces_give_an_empty_list(detector, image):
    assert _check(detector.detect(image)) == []
    assert _check(detector.track(image)) == []


@pytest.mark.parametrize("convert", [
    lambda im: im.astype(np.float32) / 255.0,
    lambda im: im.astype(np.float64),
    lambda im: im.astype(np.uint16) * 257,
    lambda im: cv2.cvtColor(im, cv2.COLOR_BGR2GRAY),
    lambda im: cv2.cvtColor(im, cv2.COLOR_BGR2BGRA),
    lambda im: np.asfortranarray(im),
    lambda im: im[:, ::-1],                     # mirrored view, negative strides
], ids=["float32-unit", "float64-255", "uint16", "grey", "bgra", "fortran", "mirrored"])
def test_other_image_types_still_find_the_face(detector, face, convert):
    faces = _check(detector.detect(convert(face)))
    assert len(faces) == 1 and faces[0].score > 0.9


def test_nan_and_inf_pixels_do_not_raise(detector, face):
    image = face.astype(np.float32)
    image[::7, ::5] = np.nan
    image[::11, ::3] = np.inf
    _check(detector.detect(image))
    _check(detector.track(image))


def test_huge_image_finds_the_face(detector, face):
    huge = cv2.resize(face, (4000, 3000), interpolation=cv2.INTER_LINEAR)
    faces = _check(detector.detect(huge))
    assert len(faces) == 1
    assert 1000 < np.ptp(faces[0].points[:, 0]) < 4000
    faces = _check(detector.track(huge))
    assert len(faces) == 1


def test_face_at_the_image_border_gives_finite_points(detector, face):
    h, w = face.shape[:2]
    shifted = np.zeros_like(face)
    shifted[:, : w // 2] = face[:, w // 2:]  # half the face cut off
    _check(detector.detect(shifted))


def test_as_bgr_uint8_keeps_uint8_bgr_as_is(face):
    out = as_bgr_uint8(face)
    assert out.dtype == np.uint8 and out.shape == face.shape
    np.testing.assert_array_equal(out, face)


def test_missing_model_directory_names_facesculpt_setup(tmp_path):
    with pytest.raises(MissingModelsError, match="facesculpt setup"):
        LandmarkDetector(tmp_path / "nowhere")
    with pytest.raises(ValueError, match="backend"):
        LandmarkDetector(tmp_path, backend="tensorflow")


@pytest.mark.parametrize("degrees", [-40.0, 25.0, 90.0])
def test_rolled_face_points_follow_the_roll(detector, face, degrees):
    """The crop turns with the eye line, so the points of a rolled frame are the upright points
    rolled (checks crop, ROI angle and back-projection together)."""
    h, w = face.shape[:2]
    upright = detector.detect(face)[0].points[:, :2]
    matrix = cv2.getRotationMatrix2D((w / 2 - 0.5, h / 2 - 0.5), degrees, 1.0)
    rolled = cv2.warpAffine(face, matrix, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    faces = _check(detector.detect(rolled))
    assert len(faces) == 1
    expected = upright @ matrix[:, :2].T + matrix[:, 2]
    eye_distance = np.linalg.norm(upright[263] - upright[33])
    error = np.linalg.norm(faces[0].points[:, :2] - expected, axis=1).mean() / eye_distance
    assert error < 0.05
