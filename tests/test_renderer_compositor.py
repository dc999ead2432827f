"""The compositor on real video frames, with real OpenGL (EGL; llvmpipe here).

Face geometry (tests/renderer_scene.py), on frame 0 of two real videos (856x480 and 512x512):
the Surrey Face Model and the face mesh fitted by the real landmark detector + fitter
(orthographic; needs `facesculpt setup`), and the Surrey Face Model posed in perspective from
hand-marked landmarks (needs no networks). The edit is the issue's (nose tip out 15 mm,
cheeks in 8 mm) solved by the deformer's ARAP and merged with its Eq. 5. Face regions for the
checks are rasterised independently with OpenCV.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from renderer_scene import (
    dilate,
    issue_edit,
    place_fitted,
    place_marked,
    psnr,
    rasterize_region,
    read_frames,
)

from facesculpt.geometry import merge_deformation
from facesculpt.nodes.renderer import Compositor
from facesculpt.nodes.renderer.gl_context import create_headless_context

VIDEOS = ("s18", "d0")
GEOMETRY = ("sfm-fitted", "facemesh-fitted", "sfm-marked")


@pytest.fixture(scope="module")
def gl():
    ctx = create_headless_context()
    yield ctx
    ctx.release()


@pytest.fixture(scope="module")
def detector(models_dir):
    from facesculpt.nodes.landmarks import LandmarkDetector

    return LandmarkDetector(models_dir)


@pytest.fixture(scope="module")
def sfm(data_dir):
    from facesculpt.nodes.fitter import load_model

    return load_model("sfm")


@pytest.fixture(scope="module", params=[(g, v) for g in GEOMETRY for v in VIDEOS], ids=lambda p: f"{p[0]}-{p[1]}")
def scene(request, data_dir, sfm):
    """(frame, placement, edit displacement) for one geometry source and video."""
    geometry, video = request.param
    frame = read_frames(data_dir, video)[0]
    if geometry == "sfm-marked":
        placement = place_marked(sfm, video)
    else:
        detector = request.getfixturevalue("detector")  # skips until `facesculpt setup` has run
        if geometry == "sfm-fitted":
            model = sfm
        else:
            from facesculpt.nodes.fitter import facemesh_model

            model = facemesh_model()
        placement = place_fitted(model, frame, detector)
    return video, frame, placement, issue_edit(placement)


def sample(image: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Bilinear samples (N, 3) float of ``image`` at pixel positions ``px`` (N, 2)."""
    m = np.asarray(px, np.float32).reshape(-1, 1, 2)
    return cv2.remap(image, m[..., 0], m[..., 1], cv2.INTER_LINEAR).reshape(-1, 3).astype(np.float64)


def test_zero_deformation_reproduces_the_frame(gl, scene):
    video, frame, pose, _ = scene
    original = frame.copy()
    H, W = frame.shape[:2]
    comp = Compositor(W, H, ctx=gl)
    out = comp.render(frame, pose.fitted, pose.projected, pose.triangles, pose.fitted.copy())
    region = rasterize_region(pose.projected, pose.triangles, (H, W))
    drawn = comp.full_frame_regions()["deformed"]
    # The face really was drawn: the GL coverage is the independently rasterised silhouette.
    assert region.sum() > 5000
    assert (drawn & region).sum() / (drawn | region).sum() > 0.97
    assert np.array_equal(out[~region], frame[~region])
    assert psnr(out[region], frame[region]) >= 40.0
    assert np.array_equal(frame, original)  # input untouched
    comp.release()


@pytest.mark.parametrize("inpaint", ["pushpull", "telea"])
def test_edit_keeps_background_and_fills_what_the_face_uncovered(gl, scene, inpaint):
    video, frame, pose, edit = scene
    H, W = frame.shape[:2]
    deformed = merge_deformation(pose.fitted, pose.R, pose.scale, edit)
    deformed_px = pose.project(deformed)
    comp = Compositor(W, H, ctx=gl, inpaint=inpaint)
    out = comp.render(frame, pose.fitted, pose.projected, pose.triangles, deformed)
    comp.release()
    original = rasterize_region(pose.projected, pose.triangles, (H, W))
    moved = rasterize_region(deformed_px, pose.triangles, (H, W))

    # No background distortion: bit-identical outside the union of both regions (+2 px).
    outside = ~dilate(original | moved, 2)
    assert np.array_equal(out[outside], frame[outside])
    assert not np.array_equal(out, frame)

    # The uncovered band (the cheeks moved in): its bulk shows background, not the old face.
    uncovered = original & ~dilate(moved, 1)
    bulk = cv2.erode(uncovered.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert bulk.sum() > 100
    assert (out[bulk] != frame[bulk]).any(axis=1).mean() >= 0.9
    # It does not depend on the old face at all: scramble every pixel of the original face
    # region and render again; the band comes out bit for bit the same.
    scrambled = frame.copy()
    scrambled[original] = 255 - scrambled[original]
    comp = Compositor(W, H, ctx=gl, inpaint=inpaint)
    again = comp.render(scrambled, pose.fitted, pose.projected, pose.triangles, deformed)
    comp.release()
    assert np.array_equal(again[bulk], out[bulk])
    assert not np.array_equal(again[moved], out[moved])  # while the face drawn there did change
    # And it looks like the background around it: each filled colour lies within the range of
    # the background colours (outside the original face) within 24 px.
    background = ~dilate(original, 1)
    window = np.ones((49, 49), np.uint8)
    lo = cv2.erode(np.where(background[..., None], frame, 255).astype(np.uint8), window)[bulk].astype(int)
    hi = cv2.dilate(np.where(background[..., None], frame, 0).astype(np.uint8), window)[bulk].astype(int)
    in_range = np.all((out[bulk] >= lo - 2) & (out[bulk] <= hi + 2), axis=1)
    assert in_range.mean() >= 0.95

    # The deformed face carries the texture from the *undeformed* projection: around the nose
    # tip (always visible here) the output at the deformed pixels is the input at the fitted ones.
    near_nose = np.linalg.norm(pose.rest - pose.rest[pose.landmarks["nose_tip"]], axis=1) < 10.0
    mapped = np.abs(sample(out, deformed_px[near_nose]) - sample(frame, pose.projected[near_nose])).mean(axis=1)
    assert np.median(mapped) <= 2.0
    if video == "s18":  # the nose moves ~4 px in the image there: the unmoved texture would not match
        unmoved = np.abs(sample(out, deformed_px[near_nose]) - sample(frame, deformed_px[near_nose])).mean(axis=1)
        assert np.median(unmoved) >= 4 * max(np.median(mapped), 0.5)


def test_frame_without_face_passes_through(gl, data_dir, sfm):
    frame = read_frames(data_dir, "s18")[0]
    H, W = frame.shape[:2]
    comp = Compositor(W, H, ctx=gl)
    empty3, empty2 = np.zeros((0, 3)), np.zeros((0, 2))
    out = comp.render(frame, empty3, empty2, sfm.triangles[:0], empty3)
    assert out is not frame and np.array_equal(out, frame)
    # A face posed entirely outside the frame draws nothing either.
    pose = place_marked(sfm, "s18")
    far = pose.fitted + np.array([5000.0, 0.0, 0.0])
    out = comp.render(frame, far, pose.project(far), pose.triangles, far)
    assert np.array_equal(out, frame)
    comp.release()


def test_bad_input_is_refused_with_a_clear_error(gl, data_dir, sfm):
    frame = read_frames(data_dir, "d0")[0]
    H, W = frame.shape[:2]
    pose = place_marked(sfm, "d0")
    comp = Compositor(W, H, ctx=gl)
    X, px, T = pose.fitted, pose.projected, pose.triangles
    with pytest.raises(ValueError, match="frame must be"):
        comp.render(frame[:100], X, px, T, X)
    with pytest.raises(ValueError, match="frame must be"):
        comp.render(frame.astype(np.float32), X, px, T, X)
    with pytest.raises(ValueError, match="one V"):
        comp.render(frame, X, px[:-1], T, X)
    bad = X.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="deformed_vertices contains NaN"):
        comp.render(frame, X, px, T, bad)
    with pytest.raises(ValueError, match="triangle indices"):
        comp.render(frame, X, px, T + len(X), X)
    with pytest.raises(ValueError, match="inpaint method"):
        Compositor(W, H, ctx=gl, inpaint="navier")
    # After the errors it still renders correctly.
    assert np.array_equal(comp.render(frame, X, px, T, X), frame)
    comp.release()
