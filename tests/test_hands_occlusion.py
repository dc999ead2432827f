"""Occlusion: with an edit active, no pixel inside the hands' region (from the hand landmarks,
:func:`hand_region_mask`) differs from the input, on the two shared photos with a hand in front
of a face; without the keep-mask the same edit does paint over the hand (so the check can fail)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facesculpt.app.pipeline import Pipeline, read_preset
from facesculpt.geometry.hand_regions import hand_region_mask, hand_size
from facesculpt.nodes.deformer import EditStack
from facesculpt.nodes.fitter import load_model
from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.nodes.hands import HandDetector
from facesculpt.nodes.landmarks.detector import Detection, LandmarkDetector


class FaceBehindTheFist(LandmarkDetector):
    """The face detector does not find the face of thumbs_down.jpg behind the fist (its best box
    is on the fist); this one is told where the face is (a box read off the photo, eyes level),
    and the face mesh does the rest (presence above 0.9 on that crop)."""

    def run_detector(self, bgr):
        cx, cy, half = 325.0, 405.0, 530.0 / 1.5 / 2.0
        eyes = np.array([[cx - 0.3 * half, cy - 0.3 * half], [cx + 0.3 * half, cy - 0.3 * half]], np.float32)
        keypoints = np.concatenate([eyes, np.repeat([[cx, cy]], 4, axis=0)]).astype(np.float32)
        return [Detection(box=np.array([cx - half, cy - half, cx + half, cy + half], np.float32),
                          keypoints=keypoints, score=0.9)]


def brow_raise() -> dict:
    """The subject's left brow raised 4 mm (ROI 30 mm): under the hand across her forehead."""
    face = load_model("facemesh")
    stack = EditStack(face.mean, face.triangles, face.landmark_names, face.landmark_vertices)
    brow = stack.landmark_vertex("left_brow")
    stack.begin([brow], roi_radius=30.0)
    stack.set_offset(brow, [0.0, 4.0, 2.0])
    return stack.to_preset()


@pytest.mark.parametrize("name, preset, detector", [
    ("google_sample_woman_hands.jpg", brow_raise, LandmarkDetector),
    ("thumbs_down.jpg", lambda: read_preset("nose_longer"), FaceBehindTheFist),
], ids=["brow_under_the_hand", "nose_behind_the_fist"])
def test_nothing_rerendered_covers_a_hand(data_dir, models_dir, name, preset, detector):
    photo = cv2.imread(str(data_dir / "hands" / name))
    h, w = photo.shape[:2]
    hands = HandDetector(models_dir).detect(photo)
    assert hands
    mask = hand_region_mask(np.stack([hand.points for hand in hands]), w, h)
    with Pipeline("facemesh", detector=detector(models_dir), fit=FitterConfig(neutral_frames=1)) as pipeline:
        pipeline.calibrate([photo], fps=1.0)
        pipeline.set_edits(preset())
        fits, timings = pipeline.analyse(photo, 0.0)
        assert fits, "no face fitted"
        painted = pipeline.compose(photo, fits, dict(timings)).image
        kept = pipeline.compose(photo, fits, dict(timings), keep_mask=mask).image
    over_hand = np.any(painted != photo, axis=2) & mask
    changed = np.any(kept != photo, axis=2)
    print(f"{name}: {over_hand.sum()} hand pixels painted without the mask, "
          f"{changed.sum()} pixels edited with it, {(changed & mask).sum()} of them in the hands")
    assert over_hand.sum() > 50  # the edit reaches the hand: without the mask it paints over it
    assert not (changed & mask).any()
    assert changed.sum() > 1000  # the edit is still there around the hand
    # The region covers the hand's joints with a margin, and not much more than the hand.
    for hand in hands:
        px = np.round(hand.points[:, :2]).astype(int)
        ok = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        assert mask[px[ok, 1], px[ok, 0]].all()
    assert mask.sum() < sum(4.0 * hand_size(hand.points) ** 2 for hand in hands)


def test_the_region_of_no_hand_is_empty_and_a_bad_hand_is_skipped():
    assert not hand_region_mask(np.zeros((0, 21, 3)), 64, 48).any()
    hand = np.full((1, 21, 2), np.nan)
    assert not hand_region_mask(hand, 64, 48).any()
