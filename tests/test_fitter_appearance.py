"""Appearance refinement (issue 20): the photometric Gauss-Newton step recovers a known pose error on
an image whose grey levels the template describes, its landmark prior holds it back, and the
fitter's option refines real frames (the benchmark, benchmarks/bench_appearance.py, measures how much)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facesculpt.geometry.projection import project
from facesculpt.geometry.vertex_normals import vertex_normals
from facesculpt.nodes.fitter import FitError, FitterConfig, make_fitter
from facesculpt.nodes.fitter.appearance import (
    AppearanceTemplate,
    Refinement,
    frontality,
    refine_pose,
    track_pose,
)
from facesculpt.nodes.fitter.surface_features import surface_features, track_features

K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])


def _scene():
    """A bumpy surface 500 mm away, an image whose grey levels are a smooth pattern, and the
    template: that pattern at the surface's true pixels."""
    ys, xs = np.mgrid[-60:61:6, -50:51:6].astype(float)
    X = np.column_stack([xs.ravel(), ys.ravel(), 500.0 - 8 * np.exp(-(xs ** 2 + ys ** 2).ravel() / 900.0)])
    gy, gx = np.mgrid[0:480, 0:640].astype(np.float32)
    image = (128 + 50 * np.sin(gx / 11.0) * np.cos(gy / 13.0) + 30 * np.sin((gx + gy) / 23.0)).astype(np.float32)
    image = cv2.GaussianBlur(image, (0, 0), 1.5)
    template = cv2.remap(image, *[project(X, K)[:, k].astype(np.float32).reshape(1, -1) for k in (0, 1)],
                         cv2.INTER_LINEAR).ravel().astype(np.float64)
    return X, image, template


def test_the_photometric_step_recovers_a_small_pose_error():
    X, image, template = _scene()
    off = Refinement(np.r_[np.radians([1.0, -1.5, 0.5]), 2.0, -1.5, 0.0]).apply(X)
    before = np.linalg.norm(project(off, K) - project(X, K), axis=1).mean()
    found = refine_pose(image, off, np.ones(len(X)), 0.8 * template + 20.0, K, np.zeros(0, np.int64))
    after = np.linalg.norm(project(found.apply(off), K) - project(X, K), axis=1).mean()
    assert before > 2.5 and after < 0.2 * before      # the gain and bias of the lighting are solved too


def test_the_landmark_prior_holds_the_pose_where_the_landmarks_put_it():
    X, image, template = _scene()
    off = Refinement(np.r_[np.radians([1.0, -1.5, 0.5]), 2.0, -1.5, 0.0]).apply(X)
    free = refine_pose(image, off, np.ones(len(X)), template, K, np.zeros(0, np.int64))
    held = refine_pose(image, off, np.ones(len(X)), template, K, np.arange(len(X)), prior_weight=100.0)
    moved = [np.linalg.norm(project(m.apply(off), K) - project(off, K), axis=1).mean() for m in (free, held)]
    assert moved[1] < 0.5 * moved[0]


def test_a_shape_component_is_recovered_with_the_pose():
    """A surface whose width is a shape component: refined from the wrong width and pose, both
    come back."""
    X, image, template = _scene()
    basis = np.zeros((len(X), 3, 1))
    basis[:, 0, 0] = (X[:, 0] - X[:, 0].mean()) * 0.05           # one std: 5 % wider
    wrong = Refinement(np.r_[np.radians([0.0, 0.5, 0.0]), 1.0, 0.0, 0.0, -1.5]).apply(X, basis)
    found = refine_pose(image, wrong, np.ones(len(X)), template, K, np.zeros(0, np.int64), basis=basis,
                        shape_weight=1e-3)
    error = [np.linalg.norm(project(Y, K) - project(X, K), axis=1).mean() for Y in (wrong, found.apply(wrong, basis))]
    assert found.shape[0] == pytest.approx(1.5, abs=0.3) and error[1] < 0.2 * error[0]


def test_the_template_learns_what_the_frame_sees_frontally():
    X, image, template = _scene()
    normals = vertex_normals(X, np.array([[0, 1, 18], [1, 19, 18]]))
    front = frontality(X, normals, perspective=True)
    assert front[[0, 1, 18, 19]].min() > 0.9 and front[5] == 0.0    # a vertex in no triangle has no normal
    learned = AppearanceTemplate(len(X))
    for _ in range(3):
        learned.update(image, project(X, K), np.ones(len(X)))
    assert np.allclose(learned.grey, template, atol=1e-3) and learned.confidence.min() == 1.0
    learned.update(image, project(X, K) + 50, np.zeros(len(X)))      # seen edge-on: nothing learned
    assert np.allclose(learned.grey, template, atol=1e-3)


def test_the_fitter_option_is_checked_and_refines_real_frames(data_dir, models_dir):
    from facesculpt.app.pipeline import Pipeline

    with pytest.raises(FitError, match="refine must be one of 'appearance', 'pose'"):
        FitterConfig(refine="pixels")
    cap = cv2.VideoCapture(str(data_dir / "video" / "d0.mp4"))
    frames = [cap.read()[1] for _ in range(14)]
    cap.release()
    fits = {}
    for refine in (None, "appearance", "pose"):
        with Pipeline("facemesh", fit=FitterConfig(refine=refine)) as pipe:
            fits[refine] = [pipe.fit_frame(f, i / 25.0) for i, f in enumerate(frames)]
            assert pipe.fitter.config.refine == refine
    for refine in ("appearance", "pose"):
        moved = [np.abs(a.projected - b.projected).max() for a, b in zip(fits[None], fits[refine])]
        assert moved[0] < 1e-3                 # nothing to track from, nothing learned yet
        assert 0.0 < max(moved[1:]) < 10.0     # then the pose moves, a little
    # a refined fit carries the landmark fit it came from (the expression measures against it)
    assert all(f.landmark_fit is None for f in fits[None])
    last = fits["appearance"][-1].landmark_fit
    assert last is not None and last.landmark_fit is None
    assert np.abs(last.projected - fits["appearance"][-1].projected).max() > 0.0
    make_fitter("facemesh", FitterConfig(refine="appearance"))  # without an image nothing changes


def _textured(size=(480, 640), seed=0) -> np.ndarray:
    """(H, W) uint8 blobs at several scales: corners everywhere."""
    rng = np.random.default_rng(seed)
    noise = sum(cv2.resize(rng.random((size[0] // c, size[1] // c)).astype(np.float32), size[::-1],
                           interpolation=cv2.INTER_CUBIC) for c in (4, 8, 16))
    return cv2.normalize(noise, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def test_corners_on_the_face_are_tracked_to_a_fraction_of_a_pixel_and_a_covered_one_is_dropped():
    X, _, _ = _scene()
    image = _textured()
    found = surface_features(image, project(X, K), np.ones(len(X), bool))
    assert found is not None and len(found) >= 50
    hull = cv2.convexHull(project(X, K).astype(np.float32))
    assert all(cv2.pointPolygonTest(hull, tuple(map(float, p)), True) >= 9 for p in found.pixels)
    mixed = np.einsum("pk,pkc->pc", found.weights, project(X, K)[found.vertices]) + found.offsets
    assert np.allclose(mixed, found.pixels) and np.allclose(found.weights.sum(axis=1), 1.0)
    # corners tracked into a frame are kept there (those off the face dropped), new ones only
    # looked for when too few remain
    kept = np.vstack([found.pixels[:100], [[2.0, 2.0]]])
    again = surface_features(image, project(X, K), np.ones(len(X), bool), kept=kept)
    assert len(again) == 100 and np.allclose(again.pixels, found.pixels[:100])
    topped = surface_features(image, project(X, K), np.ones(len(X), bool), kept=found.pixels[:20])
    assert np.allclose(topped.pixels[:20], found.pixels[:20]) and len(topped) > 50
    shift = np.float32([[1, 0, 1.3], [0, 1, -0.6]])
    moved = cv2.warpAffine(image, shift, image.shape[::-1], flags=cv2.INTER_CUBIC)
    x0, y0 = found.pixels[0].astype(int)
    moved[y0 - 12:y0 + 13, x0 - 12:x0 + 13] = 128                  # a hand over one corner
    tracked, ok, back = track_features(image, moved, found)
    assert not ok[0] and ok.mean() > 0.8
    assert back.shape == ok.shape and np.median(back[ok]) < 0.05   # the way back returns (the shift is 1.4 px)
    error = np.linalg.norm(tracked[ok] - (found.pixels[ok] + [1.3, -0.6]), axis=1)
    assert np.median(error) < 0.05


def test_the_tracked_corners_give_the_head_its_motion():
    X, _, _ = _scene()
    image = _textured()
    found = surface_features(image, project(X, K), np.ones(len(X), bool))
    truth = Refinement(np.r_[np.radians([0.8, -1.2, 0.4]), 3.0, -2.0, 5.0])
    after = project(truth.apply(X), K)
    # each corner moves with its vertices (the scene's motion, through their mix)
    seen = np.einsum("pk,pkc->pc", found.weights, after[found.vertices]) + found.offsets
    seen[:5] += 6.0                                                 # five mistracked corners
    motion = track_pose(X, K, (found.vertices, found.weights, found.offsets, seen))
    error = np.linalg.norm(project(motion.apply(X), K) - after, axis=1)
    assert np.median(error) < 0.05 and error.max() < 0.2


def test_refinement_filters_landmark_noise_on_a_still_face(data_dir, models_dir):
    """A still frame whose landmarks jitter as a whole (the head's pose noise): the refined fit
    follows the image (which does not move) and takes only a share of each frame's landmark
    noise, so it jitters less. (Noise of single points is the dense shape's, not the pose's.)"""
    from facesculpt.nodes.landmarks.detector import LandmarkDetector

    frame = cv2.VideoCapture(str(data_dir / "video" / "d0.mp4")).read()[1]
    points = LandmarkDetector(models_dir).detect(frame)[0].points.astype(np.float64)
    rng = np.random.default_rng(1)
    noisy = [points.copy() for _ in range(40)]
    for p in noisy:
        p[:, :2] += rng.normal(0, 0.8, 2)
    jitter = {}
    for refine in (None, "appearance"):
        fitter = make_fitter("facemesh", FitterConfig(refine=refine), image_size=frame.shape[1::-1])
        tracks = np.array([fitter.fit(p, stamp=i / 25.0, image=frame).projected for i, p in enumerate(noisy)])
        jitter[refine] = np.median(np.linalg.norm(np.diff(tracks[15:], axis=0), axis=2))
    assert jitter["appearance"] < 0.5 * jitter[None]


@pytest.mark.slow
def test_the_refined_shape_reaches_the_learned_neutral(data_dir, models_dir):
    """SFM: the refinement's mean shape change is part of the neutral the deformer gets."""
    from facesculpt.app.pipeline import Pipeline

    cap = cv2.VideoCapture(str(data_dir / "video" / "d0.mp4"))
    frames = [cap.read()[1] for _ in range(16)]
    cap.release()
    with Pipeline("sfm", fit=FitterConfig(refine="appearance")) as pipe:
        for i, f in enumerate(frames):
            pipe.fit_frame(f, i / 25.0)
        fitter = pipe.fitter
        change = fitter.refiner.shape_change
        assert change is not None and np.abs(change).max() > 0
        alpha = fitter._alpha.astype(np.float32).copy()
        without = fitter.model.instance(alpha)
        alpha[:len(change)] += change.astype(np.float32)
        assert np.allclose(fitter.neutral, fitter.model.instance(alpha)) and np.abs(fitter.neutral - without).max() > 0.01


def test_the_applied_shape_follows_the_mean_of_the_samples_without_its_wobble():
    """A shape sample, taken every SHAPE_EVERY-th frame, joins the running mean in equal parts
    over the frames until the next (the mean does not step at the samples' rhythm); the shape the
    fits carry follows that mean smoothly, frame by frame, and reaches it."""
    from facesculpt.nodes.fitter import appearance
    from facesculpt.nodes.fitter.appearance_refiner import AppearanceRefiner

    refiner = AppearanceRefiner(K, "perspective", learn_frames=0)
    rng = np.random.default_rng(3)
    truth = np.array([1.0, -0.5, 0.25])
    every = appearance.SHAPE_EVERY
    assert every > 1
    applied, means = [], []
    for i in range(60 * every):
        sample = truth + rng.normal(0, 0.5, 3) if i % every == 0 else None
        applied.append(refiner._mean_shape(sample, 3).copy())
        means.append(refiner.shape_sum / refiner.shape_count)
    applied, means = np.array(applied), np.array(means)
    step = lambda a, n: np.linalg.norm(np.diff(a[10 * every::n], axis=0), axis=1).max()  # noqa: E731
    assert step(means, 1) < 0.5 * step(means, every)     # no step at the samples' rhythm
    assert step(applied, 1) < 0.5 * step(means, every)   # the largest step from frame to frame: the visible wobble
    assert np.abs(applied[-1] - means[-1]).max() < 0.1 and np.abs(means[-1] - truth).max() < 0.25
    assert np.array_equal(refiner.shape_change, applied[-1])


@pytest.mark.slow
def test_the_refinement_brings_the_synthetic_heads_outline_and_shape_closer(data_dir, models_dir):
    """SFM on the realism benchmark's synthetic head (true pose and shape known): refined, the
    vertices at the head's outline land at least a fifth closer to the true ones than the landmark fit's, and the
    learned neutral is closer to the true shape (the person's size comes from the pixels)."""

    from benchmarks.bench_appearance import run
    from benchmarks.realism.posed import render_all
    from benchmarks.realism.scene import make_scene

    scene = make_scene(data_dir, frames=45)
    truths = render_all(scene, [(0.0, 0.0)], 2)[(0.0, 0.0)]
    frames = [t["image"] for t in truths]
    got = {}
    for refine in (None, "appearance"):
        bins, snr, _ = run(frames, truths, scene.background, scene, {"refine": refine})
        got[refine] = (np.mean([b["outline_px"] for b in bins.values()]), snr)
    assert got["appearance"][0] < 0.8 * got[None][0]
    assert got["appearance"][1] > got[None][1] + 1.0


def test_the_complementary_filter_trusts_the_frame_more_while_the_head_moves():
    from facesculpt.nodes.fitter import appearance

    speeds = [0.0, 0.5, 1.0, 2.0, 5.0]
    shares = [appearance.blend(v) for v in speeds]
    assert shares[0] == appearance.BLEND and shares[-1] == appearance.BLEND_MOVING > appearance.BLEND
    assert all(a < b for a, b in zip(shares[:4], shares[1:4]))
