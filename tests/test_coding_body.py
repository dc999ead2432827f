"""The decoder's body motion (issue 51, facesculpt/nodes/renderer/body_motion.py): the head's sway carried over
the neck and body below the jaw, on plain arrays and on a real coded video (d0)."""

from __future__ import annotations

import numpy as np
import pytest

from facesculpt.nodes.renderer.body_motion import body_box, body_weight, carry_to_body, neck_motion
from facesculpt.nodes.renderer.source_map import UNCOVERED


def _face_grid(shift=(0.0, 0.0, 0.0)):
    """A flat-ish face (a grid 120 mm wide, 160 mm high, bulging 20 mm toward the camera) 600 mm in
    front of a camera with f = 500 px, its centre at (200, 150) px, moved by ``shift`` mm."""
    xs, ys = np.meshgrid(np.linspace(-60, 60, 13), np.linspace(-80, 80, 17))
    z = 600.0 - 20.0 * np.cos(xs / 60 * np.pi / 2) * np.cos(ys / 80 * np.pi / 2)
    X = np.column_stack([xs.ravel(), ys.ravel(), z.ravel()]) + np.asarray(shift)
    P = np.array([[500.0, 0, 200, 0], [0, 500.0, 150, 0], [0, 0, 1, 0]])
    x = X @ P[:, :3].T
    return X, x[:, :2] / x[:, 2:], P


def test_a_sway_moves_the_neck_sideways_and_a_nod_hardly_at_all():
    fitted, projected, P = _face_grid()
    swayed, _, _ = _face_grid((12.0, 9.0, 0.0))   # 10 px right, 7.5 px down on screen
    m = neck_motion(fitted, projected, swayed, P)
    assert m[0] < -8.0 and abs(m[1]) < 1e-9      # the output's neck takes its colour 10 px to the left
    c, s = np.cos(np.radians(8)), np.sin(np.radians(8))
    pivot = np.array([0.0, 80.0, 600.0 + 0.35 * 160.0])  # behind the chin, as neck_motion places it
    nodded = (fitted - pivot) @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]]).T + pivot
    assert abs(neck_motion(fitted, projected, nodded, P)[0]) < 0.5


def test_the_body_below_the_chin_takes_the_motion_and_nothing_far_away_moves():
    h, w = 300, 200
    offsets = np.full((h, w, 2), UNCOVERED, np.float32)
    face = np.zeros((h, w), bool)
    face[40:140, 50:150] = True
    offsets[face] = (3.0, 1.0)
    dst = np.array([[50.0, 40.0], [150.0, 40.0], [50.0, 140.0], [150.0, 140.0], [100.0, 140.0]])
    out = carry_to_body(offsets, face, (0, 0), dst, np.array([-5.0, 0.0]))
    assert np.array_equal(out[face], offsets[face])            # the face itself is untouched
    assert -5.0 <= out[190, 100, 0] < -3.0 and out[190, 100, 1] == 0.0  # the neck, below the chin, sways
    assert (out[20, 5] == UNCOVERED).all()                      # beside the hair: nothing
    assert (out[299, 0] == UNCOVERED).all() or np.abs(out[299, 0]).max() < 5.0
    b = body_weight((h, w), (0, 0), (50.0, 40.0, 150.0, 140.0), 100.0)
    assert b[:150].max() == 0.0 and b[150:, 100].max() > 0.8     # nothing above the chin, most of it below
    assert b[299, 100] < b[200, 100] and b[200, 0] < b[200, 100]  # less down the body and beside it
    assert np.abs(np.diff(b, axis=0)).max() < 0.1 and np.abs(np.diff(b, axis=1)).max() < 0.1  # no hard edge
    box = body_box(dst, w, h)  # from below the chin to 1.5 face heights down
    assert box[1] >= 140 and box[3] == 291 and box[2] - box[0] > 150


@pytest.mark.slow
def test_decoded_neck_band_is_not_worse_with_the_body_motion(data_dir, models_dir, tmp_path):
    """On d0's first 40 frames, the band below the jaw is at least as close to the input with the
    body motion as without (the decoder before issue 51), and the face region is unchanged."""
    import cv2

    from facesculpt.app.coding import analyse, decode_file, encode, face_region_quality, neck_band, region_psnr

    cap, frames = cv2.VideoCapture(str(data_dir / "video" / "d0.mp4")), []
    while len(frames) < 40:
        frames.append(cap.read()[1])
    analysis = analyse(frames, cap.get(cv2.CAP_PROP_FPS), neutral_frames=10)
    encode(analysis, tmp_path / "d0.fsc", components=12)
    scores = {}
    for body in (False, True):
        _, decoder = decode_file(tmp_path / "d0.fsc", body_motion=body)
        try:
            out = [decoder.frame(i) for i in range(len(frames))]
        finally:
            decoder.close()
        p = analysis.projected
        scores[body] = (np.mean([region_psnr(o, f, neck_band(f.shape, q)) for o, f, q in zip(out, frames, p)]),
                        np.mean([face_region_quality(o, f, q)[0] for o, f, q in zip(out, frames, p)]))
    assert scores[True][0] >= scores[False][0] - 0.05
    assert abs(scores[True][1] - scores[False][1]) < 0.1
