"""The background behind the face (issue 16): the background plate (learning behind a moving
occluder, registration under a known camera motion, ageing out), the patch fill against
push-pull and OpenCV's inpainting on a stripe pattern, and the compositor with the plate on over
a static synthetic scene whose true background is known. Real OpenGL (EGL) for the compositor."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from benchmarks.renderer_scene import plane_mesh
from facesculpt.nodes.renderer import Compositor
from facesculpt.nodes.renderer.background_plate import BackgroundPlate, face_region
from facesculpt.nodes.renderer.gl_context import create_headless_context
from facesculpt.nodes.renderer.inpaint import fill_by_parts

W, H = 320, 240


def cluttered(w: int, h: int, seed: int = 0) -> np.ndarray:
    """A sharp, cluttered (h, w, 3) uint8 background: random rectangles and lines over noise."""
    rng = np.random.default_rng(seed)
    img = rng.integers(60, 200, (h, w, 3), dtype=np.uint8)
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    for _ in range(w * h // 400):
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        colour = tuple(int(c) for c in rng.integers(0, 256, 3))
        if rng.random() < 0.5:
            cv2.rectangle(img, (x, y), (x + int(rng.integers(3, 25)), y + int(rng.integers(3, 25))), colour, -1)
        else:
            cv2.line(img, (x, y), (x + int(rng.integers(-30, 30)), y + int(rng.integers(-30, 30))), colour, 2)
    return img


def disc(shape, centre, radius) -> np.ndarray:
    mask = np.zeros(shape, np.uint8)
    cv2.circle(mask, (int(round(centre[0])), int(round(centre[1]))), int(radius), 1, -1)
    return mask


def test_plate_learns_a_static_background_behind_a_moving_occluder():
    bg = cluttered(W, H)
    plate = BackgroundPlate(W, H)
    seen_ever = np.zeros((H, W), bool)
    for i in range(30):
        centre = (60 + 7 * i, 120)
        frame = bg.copy()
        frame[disc((H, W), centre, 40) != 0] = (40, 90, 200)
        occluded = disc((H, W), centre, 46)
        plate.update(frame, occluded)
        seen_ever |= occluded == 0
        assert not plate.moved  # a static camera: never warped
    known = plate.known()
    assert np.array_equal(known, seen_ever)
    err = np.abs(plate.colour[known] - bg[known].astype(np.float32))
    assert err.max() < 0.5  # the same background every time: its exact colours
    # Behind the last position, what the occluder covered earlier in its path is known too.
    last = disc((H, W), (60 + 7 * 29, 120), 40) != 0
    assert known[last].mean() > 0.4


def test_plate_follows_a_known_homography():
    big = cluttered(W + 80, H + 80, seed=3)
    plate = BackgroundPlate(W, H)
    truth = None
    for i in range(12):
        a = np.deg2rad(0.3 * i)
        # The camera turns and pans: the frame is the big image seen through a moving homography.
        Hm = np.array([[np.cos(a), -np.sin(a), 40 - 2.5 * i], [np.sin(a), np.cos(a), 40 - 1.5 * i],
                       [1e-6 * i, 0.0, 1.0]])
        truth = cv2.warpPerspective(big, np.linalg.inv(Hm), (W, H), flags=cv2.INTER_LINEAR)
        frame = truth.copy()
        centre = (100 + 8 * i, 120)
        frame[disc((H, W), centre, 35) != 0] = (30, 200, 60)
        plate.update(frame, disc((H, W), centre, 40))
    assert plate.homography is not None
    known = plate.known()
    # Pixels the occluder hides now, seen in earlier frames at other places in the image.
    hidden = (disc((H, W), (100 + 8 * 11, 120), 35) != 0) & known
    assert hidden.sum() > 500
    err = np.abs(plate.colour[hidden] - truth[hidden].astype(np.float32)).mean()
    assert err < 12.0, err
    # Without registration the same pixels would hold the background of another place.
    first = cv2.warpPerspective(big, np.linalg.inv(np.array([[1, 0, 40], [0, 1, 40], [0, 0, 1.0]])), (W, H))
    assert np.abs(first[hidden].astype(np.float32) - truth[hidden]).mean() > 2 * err


def test_plate_ages_out():
    bg = cluttered(W, H, seed=5)
    plate = BackgroundPlate(W, H, max_age=5)
    plate.update(bg, None)
    assert plate.known().all()
    still = disc((H, W), (160, 120), 50)
    for _ in range(5):
        plate.update(bg, still)
    assert plate.known()[still != 0].all()  # seen 5 frames ago: still fresh
    plate.update(bg, still)
    assert not plate.known()[still != 0].any()  # 6 frames: aged out
    assert plate.known()[still == 0].all()


def test_face_region_is_the_hull_grown_by_the_margin():
    pts = np.array([[100, 100], [200, 100], [200, 160], [100, 160], [150, 130]], float)
    m = face_region((H, W), pts, 5)
    assert m[95, 150] and m[165, 150] and m[130, 95] and m[130, 205]
    assert not m[92, 150] and not m[130, 208]


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return 10 * np.log10(255.0 ** 2 / max(float(((a.astype(float) - b) ** 2).mean()), 1e-9))


def test_patch_fill_continues_stripes_better_than_pushpull_and_cv2_inpaint():
    yy, xx = np.mgrid[0:160, 0:240]
    wave = (127 + 90 * np.sin(2 * np.pi * (xx + 0.4 * yy) / 13.0)).astype(np.uint8)
    img = np.dstack([wave, 255 - wave, np.full_like(wave, 128)])
    fill = np.zeros((160, 240), np.uint8)
    cv2.ellipse(fill, (120, 80), (70, 45), 0, 200, 340, 1, 10)  # a band, as a narrowed jaw leaves
    source = fill == 0
    region = fill != 0
    got = {m: psnr(fill_by_parts(img, fill, source, m)[region], img[region])
           for m in ("pushpull", "telea", "ns", "patch")}
    assert got["patch"] > got["pushpull"] + 6.0, got
    assert got["patch"] > max(got["telea"], got["ns"]) + 6.0, got


@pytest.fixture(scope="module")
def gl():
    ctx = create_headless_context()
    yield ctx
    ctx.release()




def test_compositor_with_the_plate_uncovers_the_true_background(gl):
    """A 'face' (a textured square) slides over a static cluttered background, then is narrowed by
    a quarter: with the plate on, the uncovered strips are the true background; push-pull's are not."""
    bg = cluttered(W, H, seed=11)
    face_tex = cv2.GaussianBlur(cluttered(W, H, seed=12), (0, 0), 3.0)
    errors = {}
    for plate in (True, False):
        comp = Compositor(W, H, ctx=gl, plate=plate)
        for i in range(16):
            cx = 70 + 10 * i
            vertices, projected, triangles = plane_mesh((cx, 120), 90, n=10)
            frame = bg.copy()
            inside = np.zeros((H, W), bool)
            inside[75:166, cx - 45:cx + 46] = True
            frame[inside] = face_tex[inside]
            deformed = vertices
            if i == 15:
                deformed = vertices.copy()
                deformed[:, 0] = cx + 0.75 * (vertices[:, 0] - cx)
            out = comp.render(frame, vertices, projected, triangles, deformed)
        x0, y0, x1, y1 = comp.box
        uncovered = np.zeros((H, W), bool)
        # inside the old outline: the fill's rim past it is the outline band's (moved with the face)
        uncovered[y0:y1, x0:x1] = ((comp.inpainted_region != 0) & (comp.deformed_region == 0)
                                   & (comp.original_region != 0))
        assert uncovered.sum() > 1000
        errors[plate] = np.abs(out[uncovered].astype(float) - bg[uncovered]).mean()
        if plate:
            assert comp.plate_region is not None and comp.plate_region.max() == 1.0
            assert "plate" in comp.timings
        comp.release()
    # not 0: on the square's top and bottom rows, just past its fitted outline, a strip pixel's drag
    # lands on the square, so it shows that row (the rim the fit lies inside), not the plate
    assert errors[True] < 4.0, errors
    assert errors[False] > 3 * errors[True], errors


def test_drag_fill_samples_past_the_offsets_and_never_the_face():
    """drag_fill takes each fill pixel from the frame at its dragged offset, unless that lands on
    the face (those are left for another fill)."""
    from facesculpt.nodes.renderer.drag_fill import drag_fill
    from facesculpt.nodes.renderer.source_map import UNCOVERED

    frame = np.zeros((60, 80, 3), np.uint8)
    frame[..., 0] = np.arange(80, dtype=np.uint8)[None, :]   # blue = x, green = y: where a sample came from
    frame[..., 1] = np.arange(60, dtype=np.uint8)[:, None]
    origin = (10, 5)                    # the crop is the frame's box [10:50] x [5:45]
    crop = np.full((40, 40, 3), 255, np.uint8)
    face = np.zeros((40, 40), np.uint8)
    face[:, :20] = 1                    # the face, before and after, on the crop's left half
    fill = np.zeros((40, 40), np.uint8)
    fill[:, 20:26] = 1                  # what it uncovered, beside it
    dragged = np.full((40, 40, 2), UNCOVERED, np.float32)
    dragged[:20, 20:26] = (6.0, 0.0)    # upper half: dragged 6 px outward, past the face
    dragged[20:, 20:26] = (-8.0, 0.0)   # lower half: into the face
    done = drag_fill(crop, frame, fill, dragged, face, origin)
    assert done[:20, 20:26].all() and not done[20:].any() and not done[:, :20].any()
    ys, xs = np.nonzero(done)
    assert np.array_equal(crop[ys, xs, 0], xs + origin[0] + 6)
    assert np.array_equal(crop[ys, xs, 1], ys + origin[1])
    assert (crop[~done] == 255).all()   # the rest untouched


def test_compositor_drag_fill_continues_the_background_into_the_gap(gl):
    """A 'face' (a flat colour) narrowed by a quarter over a background of vertical stripes: the
    drag fill gives the uncovered strips the stripes (their edges, none of the face's colour);
    push-pull gives a smear of them."""
    x = np.arange(W)
    bg = np.zeros((H, W, 3), np.uint8)
    bg[:] = np.where((x // 4) % 2 == 0, 60, 200).astype(np.uint8)[None, :, None]
    face_colour = np.array([30, 30, 230], np.uint8)
    cx = 160
    vertices, projected, triangles = plane_mesh((cx, 120), 90, n=10)
    frame = bg.copy()
    frame[75:166, cx - 45:cx + 46] = face_colour
    deformed = vertices.copy()
    deformed[:, 0] = cx + 0.75 * (vertices[:, 0] - cx)
    contrast = {}
    for fill in ("drag", "pushpull"):
        with Compositor(W, H, ctx=gl, inpaint=fill) as comp:
            out = comp.render(frame, vertices, projected, triangles, deformed)
            x0, y0, x1, y1 = comp.box
            gap = np.zeros((H, W), bool)
            gap[y0:y1, x0:x1] = (comp.inpainted_region != 0) & (comp.deformed_region == 0) & (comp.original_region != 0)
            comp_face = np.zeros((H, W), np.uint8)
            comp_face[y0:y1, x0:x1] = comp.deformed_region
        gap[:80] = gap[162:] = False    # away from the corners, where the face's top and bottom edges meet it
        # and 2 px from the new outline: the face's last column, half outside the fitted outline, moves in with it
        gap &= cv2.dilate(comp_face, np.ones((5, 5), np.uint8)) == 0
        assert gap.sum() > 500
        values = out[gap].astype(int)
        pairs = gap[:, :-1] & gap[:, 1:]    # horizontal neighbours both in the gap: the stripes' edges
        contrast[fill] = np.abs(np.diff(out[..., 1].astype(int), axis=1))[pairs].mean()
        if fill == "drag":
            assert (np.abs(values - face_colour).sum(axis=1) > 60).all()   # no face colour in the gap
    background = np.abs(np.diff(bg[..., 1].astype(int), axis=1)).mean()
    assert contrast["drag"] > 0.6 * background, (contrast, background)   # the stripes, squeezed
    assert contrast["pushpull"] < 0.3 * contrast["drag"], contrast        # a smear


def test_the_dragged_offsets_are_smoothed_over_the_gap_only():
    """Two constant patches of dragged offsets meet in the gap (the nearest-pixel mosaic): smoothed,
    the jump at their seam spreads over a few pixels; the face's own offsets and unset pixels stay."""
    from facesculpt.nodes.renderer.drag_fill import smooth_drag
    from facesculpt.nodes.renderer.source_map import UNCOVERED

    dragged = np.full((40, 40, 2), UNCOVERED, np.float32)
    dragged[:, :20] = (4.0, 0.0)
    dragged[:, 20:30] = (8.0, 0.0)           # columns 30-39: nothing set
    gap = np.zeros((40, 40), bool)
    gap[10:30, 10:36] = True
    out = smooth_drag(dragged, gap, 3.0)
    np.testing.assert_array_equal(out[~gap], dragged[~gap])
    assert (out[10:30, 30:36, 0] == UNCOVERED).all()
    row = out[20, 10:30, 0]
    assert np.all(np.diff(row) >= 0) and np.abs(np.diff(row)).max() < 1.5  # 4 -> 8 in steps, not one jump
    assert abs(row[0] - 4.0) < 0.05 and abs(out[20, 29, 0] - 8.0) < 1.0
