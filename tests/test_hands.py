"""Hands: the palm detector and hand landmark networks converted by the project's own converter
against ai-edge-litert running the originals (real crops from the shared hand photos), and
:class:`HandDetector` on those photos (every clearly visible hand, handedness where it is
unambiguous, tracking of a moving hand)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from detector_checks import reader_matches_litert

from facesculpt.networks import LiteRtNetwork, OnnxNetwork
from facesculpt.nodes.hands.detector import (
    HAND_SIZE,
    HandDetector,
    crop_image,
    letterbox_roi,
)
from facesculpt.nodes.hands.palm import PALM_SIZE
from facesculpt.paths import MissingModelsError

Interpreter = pytest.importorskip("ai_edge_litert.interpreter").Interpreter

# Per photo, left to right in the image (by the wrist): each clearly visible hand, as the
# person's hand ("right"/"left") where that is unambiguous, else None.
PHOTOS = {
    "google_sample_woman_hands.jpg": ["left", "right"],  # bottom-left hand (her left), top hand (her right)
    "pointing_up.jpg": ["left"],
    "thumbs_down.jpg": ["right"],
    "thumbs_up.jpg": [None],  # her body turned away: either hand could hold the thumb up
    "victory.jpg": ["right"],
}


@pytest.fixture(scope="module")
def photos(data_dir):
    folder = data_dir / "hands"
    return {name: cv2.imread(str(folder / name)) for name in PHOTOS}


@pytest.fixture(scope="module")
def found(models_dir, photos):
    detector = HandDetector(models_dir, max_hands=2)
    return {name: detector.detect(image) for name, image in photos.items()}


def test_reader_sees_the_tensors_and_operators_litert_sees(models_dir):
    for name in ("palm_detector", "hand_landmark"):
        operators = reader_matches_litert(models_dir / f"{name}.tflite", Interpreter)
        assert {"MEAN", "FULLY_CONNECTED", "RESIZE_BILINEAR"} & set(operators)


def _inputs(photos, found):
    """Palm-detector inputs (letterboxed photos, also mirrored) and hand crops (the crops the
    detector used, also shifted and turned a little)."""
    palm_inputs, hand_inputs = [], []
    for name, image in photos.items():
        rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
        h, w = rgb.shape[:2]
        for img in (rgb, rgb[:, ::-1].copy()):
            patch = crop_image(img, letterbox_roi(w, h), PALM_SIZE, cv2.BORDER_CONSTANT)
            palm_inputs.append(patch.astype(np.float32) / 255.0)
        for hand in found[name]:
            for dx, angle in ((0.0, 0.0), (0.08, 0.2), (-0.08, -0.3)):
                roi = hand.roi.astype(np.float64)
                roi[:2] += 0.5 + dx * roi[2]
                roi[4] += angle
                hand_inputs.append(crop_image(rgb, roi, HAND_SIZE).astype(np.float32) / 255.0)
    return palm_inputs, hand_inputs


def test_hand_networks_match_litert_on_real_crops(models_dir, photos, found):
    palm_inputs, hand_inputs = _inputs(photos, found)
    assert len(palm_inputs) == 10 and len(hand_inputs) >= 18
    ours, ref = OnnxNetwork(models_dir / "palm_detector.onnx"), LiteRtNetwork(models_dir / "palm_detector.tflite")
    worst_box = worst_score = 0.0
    for x in palm_inputs:
        (boxes, logits), (ref_boxes, ref_logits) = ours.run(x[None]), ref.run(x[None])
        worst_box = max(worst_box, float(np.abs(boxes - ref_boxes).max()) / PALM_SIZE)
        sig = [1 / (1 + np.exp(-np.clip(v.astype(np.float64), -100, 100))) for v in (logits, ref_logits)]
        worst_score = max(worst_score, float(np.abs(sig[0] - sig[1]).max()))
    ours, ref = OnnxNetwork(models_dir / "hand_landmark.onnx"), LiteRtNetwork(models_dir / "hand_landmark.tflite")
    worst_points = worst_flags = 0.0
    for x in hand_inputs:
        a, b = ours.run(x[None]), ref.run(x[None])
        assert [o.shape for o in a] == [r.shape for r in b]
        worst_points = max(worst_points, float(np.abs(a[0] - b[0]).max()) / HAND_SIZE)
        worst_flags = max(worst_flags, float(np.abs(a[1] - b[1]).max()), float(np.abs(a[2] - b[2]).max()))
        assert b[1].item() > 0.5  # these really are hands
    print(f"palm: box {worst_box:.2e} of the input, score {worst_score:.2e}; "
          f"hand: points {worst_points:.2e} of the crop, presence/handedness {worst_flags:.2e}")
    assert worst_box <= 1e-3 and worst_score <= 1e-3
    assert worst_points <= 1e-3 and worst_flags <= 1e-3


def test_every_clearly_visible_hand_is_found_with_its_handedness(photos, found):
    for name, expected in PHOTOS.items():
        hands = sorted(found[name], key=lambda hand: hand.points[0, 0])
        assert len(hands) == len(expected), (name, len(hands))
        h, w = photos[name].shape[:2]
        for hand, side in zip(hands, expected):
            assert hand.score > 0.9, name
            inside = (hand.points[:, 0] > -0.05 * w) & (hand.points[:, 0] < 1.05 * w) & (hand.points[:, 1] < 1.05 * h)
            assert inside.all(), name
            if side is not None:
                assert hand.handedness == side, (name, hand.right)
    # The hand's size is the hand's: the pointing hand spans a good part of its 419-pixel photo.
    pointing = found["pointing_up.jpg"][0].points
    assert 60 < np.ptp(pointing[:, 1]) < 220
    assert pointing[8, 1] < pointing[0, 1] - 50  # the index tip points up, above the wrist


def test_litert_backend_gives_the_same_hands(models_dir, photos, found):
    reference = HandDetector(models_dir, max_hands=2, backend="litert")
    for name, image in photos.items():
        ref = reference.detect(image)
        assert len(ref) == len(found[name])
        for ours, theirs in zip(found[name], ref):
            assert np.abs(ours.points[:, :2] - theirs.points[:, :2]).max() <= 1e-3 * float(ours.roi[2])
            assert ours.handedness == theirs.handedness


def test_tracking_follows_a_moving_hand_without_the_palm_detector(models_dir, photos):
    image = photos["pointing_up.jpg"]
    detector = HandDetector(models_dir, max_hands=1)
    first = detector.track(image)
    assert len(first) == 1 and detector.last_ran_detector
    h, w = image.shape[:2]
    for step in range(1, 9):
        shift = np.float32([[1, 0, 6 * step], [0, 1, 3 * step]])
        moved = cv2.warpAffine(image, shift, (w, h), borderMode=cv2.BORDER_REPLICATE)
        hands = detector.track(moved)
        assert len(hands) == 1 and not detector.last_ran_detector and hands[0].track_id == first[0].track_id
        offset = (hands[0].points[:, :2] - first[0].points[:, :2]).mean(axis=0)
        assert np.allclose(offset, [6 * step, 3 * step], atol=3.0), offset


def test_no_hand_and_bad_input_give_an_empty_list(models_dir, tmp_path):
    detector = HandDetector(models_dir)
    assert detector.track(np.full((240, 320, 3), 127, np.uint8)) == []
    assert detector.track(np.zeros((0, 0, 3), np.uint8)) == []
    assert detector.track("not an image") == []
    with pytest.raises(MissingModelsError, match="facesculpt setup"):
        HandDetector(tmp_path)
