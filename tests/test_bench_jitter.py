"""The jitter measures of the appearance-fitting benchmark (benchmarks/realism/jitter.py): the
metric, the degraded synthetic frames, the tracker of the face's own image motion, and the still
synthetic head. The full benchmark (benchmarks/bench_appearance.py) is not run here."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from benchmarks.realism.jitter import affine_motion, degraded, jitter, low_passed, still_steps, tracked_motion
from benchmarks.realism.scene import MOTIONS, head_pose


def _smooth_tracks(frames: int = 60, vertices: int = 40) -> np.ndarray:
    """(F, V, 2) px: points drifting slowly and smoothly (0.2 px a frame at most)."""
    rng = np.random.default_rng(1)
    base = rng.uniform(100, 300, (vertices, 2))
    t = np.arange(frames)[:, None, None]
    return base[None] + np.concatenate([3.0 * np.sin(2 * np.pi * t / 90), 2.0 * np.cos(2 * np.pi * t / 70)], axis=2)


def test_jitter_is_what_is_not_smooth():
    tracks = _smooth_tracks()
    smooth, still = jitter(tracks)
    assert smooth < 0.005 and still == len(tracks) - 1 - 6
    rng = np.random.default_rng(2)
    shake = rng.normal(0, 0.1, (len(tracks), 1, 2))          # the whole mesh shaking together
    shaken, _ = jitter(tracks + shake)
    assert 0.08 < shaken < 0.2
    # a fast move is not a still frame
    moving = tracks + np.arange(len(tracks))[:, None, None] * 3.0
    assert jitter(moving)[1] == 0 and np.isnan(jitter(moving)[0])
    # unless the frames to take are given: those of another track
    steady = jitter(moving, still=still_steps(tracks))
    assert steady[1] == still and steady[0] < 0.005


def test_the_low_pass_keeps_a_still_track_and_calms_a_shaking_one():
    tracks = _smooth_tracks()
    rng = np.random.default_rng(3)
    shaken = tracks + rng.normal(0, 0.1, (len(tracks), 1, 2))
    assert jitter(low_passed(shaken, 1.5))[0] < 0.5 * jitter(shaken)[0]
    still = np.repeat(tracks[:1], 20, axis=0)
    assert np.allclose(low_passed(still, 1.5), still)


def test_the_affine_fit_discounts_a_few_corners_that_move_on_their_own():
    rng = np.random.default_rng(4)
    a = rng.uniform(0, 200, (80, 2))
    M = np.array([[1.01, 0.02, 0.3], [-0.02, 0.99, -0.2]])
    b = a @ M[:, :2].T + M[:, 2]
    b[:8] += rng.uniform(2, 4, (8, 2))                      # a mouth talking
    got = affine_motion(a, b)
    assert np.abs(got - M).max() < 0.01
    plain = np.linalg.lstsq(np.c_[a, np.ones(len(a))], b, rcond=None)[0].T
    assert np.abs(plain - M)[:, 2].max() > 5 * np.abs(got - M)[:, 2].max()


def _photo_frames(data_dir: Path, shifts: np.ndarray) -> tuple[list, np.ndarray]:
    """A hand-marked photo's face moved by the sub-pixel ``shifts`` (F, 2) px, and the points of a
    grid on its face, (F, V, 2) px, moved alike."""
    photos = sorted((data_dir / "faces").glob("*.jpg"))
    if not photos:
        pytest.skip("the shared photos are missing")
    image = cv2.imread(str(photos[0]))
    h, w = image.shape[:2]
    x, y = np.meshgrid(np.linspace(0.3 * w, 0.7 * w, 8), np.linspace(0.3 * h, 0.7 * h, 8))
    grid = np.c_[x.ravel(), y.ravel()]
    frames = [cv2.warpAffine(image, np.float64([[1, 0, dx], [0, 1, dy]]), (w, h), flags=cv2.INTER_CUBIC,
                             borderMode=cv2.BORDER_REFLECT) for dx, dy in shifts]
    return frames, grid[None] + shifts[:, None, :]


def test_the_tracker_follows_the_pixels_from_frame_to_frame_to_a_tenth_of_a_pixel(data_dir):
    rng = np.random.default_rng(5)
    shifts = np.cumsum(rng.uniform(-0.6, 0.6, (12, 2)), axis=0)
    shifts -= shifts[0]
    frames, truth = _photo_frames(data_dir, shifts)
    got = tracked_motion(frames, truth)
    assert got.shape == truth.shape and np.array_equal(got[0], truth[0])
    step_error = lambda tracks: np.abs(np.diff(tracks, axis=0) - np.diff(truth, axis=0)).max()  # noqa: E731
    assert step_error(got) < 0.1
    assert step_error(np.repeat(truth[:1], len(truth), axis=0)) > 0.5     # the shifts are there to follow
    # the points it carries are the first frame's, whatever the later frames' fit says
    wrong = truth + rng.normal(0, 2.0, truth.shape) * (np.arange(len(truth)) > 0)[:, None, None]
    assert step_error(tracked_motion(frames, wrong)) < 0.1


def test_degraded_frames_are_noisy_and_encoded_into_the_given_folder(tmp_path, data_dir):
    frames, _ = _photo_frames(data_dir, np.zeros((6, 2)))
    assert all(a is b for a, b in zip(degraded(frames, 0.0, None, tmp_path), frames))
    noisy = degraded(frames, 3.0, None, tmp_path)
    spread = np.std(noisy[0].astype(float) - frames[0].astype(float))
    assert 2.5 < spread < 3.5
    encoded = degraded(frames, 3.0, 23, tmp_path)
    assert len(encoded) == len(frames) and encoded[0].shape == frames[0].shape
    assert [p.suffix for p in tmp_path.iterdir()] == [".mp4"]
    loss = np.abs(encoded[0].astype(float) - noisy[0].astype(float)).mean()
    assert 0.5 < loss < 10


def test_the_still_head_barely_moves_and_the_turning_one_turns():
    assert MOTIONS == ("turning", "still")
    still = np.array([head_pose(i, "still")[0] for i in range(180)])
    turning = np.array([head_pose(i)[0] for i in range(180)])
    assert np.ptp(turning) > 45 and np.ptp(still) < 6
    assert np.abs(np.diff(still)).max() < 0.1 < np.abs(np.diff(turning)).max()
    with pytest.raises(ValueError, match="still"):
        head_pose(0, "spinning")
