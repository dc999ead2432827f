"""The renderer's parts: the fills on real pixels, camera recovery, hole closing, video output."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from benchmarks.renderer_scene import read_frames
from facesculpt.geometry import boundary_loops, point_bounds
from facesculpt.geometry.close_holes import close_holes
from facesculpt.geometry.subdivision import loop_subdivision
from facesculpt.nodes.renderer.camera import estimate_projection, project
from facesculpt.nodes.renderer.compositor_options import OUTLINE_BAND
from facesculpt.nodes.renderer.frame_size_defaults import (
    AUTO_MAX_FINE_EDGE_PX,
    auto_interpolation,
    auto_outline_band,
    auto_subdivision,
)
from facesculpt.nodes.renderer.inpaint import fill_by_parts, fill_pushpull, fill_telea, part_boxes, uncovered_mask
from facesculpt.nodes.renderer.mesh import vertex_rings
from facesculpt.nodes.renderer.sinc_sampling import MARGIN_PX, Upsampled, sample_sinc, upsample2x, upsampled_over
from facesculpt.nodes.renderer.subdivision import MAX_FINE_EDGE_PX, levels_for, median_edge_px
from facesculpt.nodes.renderer.video_out import VideoOutput
from facesculpt.nodes.renderer.warp import sample


# -- sampling -------------------------------------------------------------------------------
def shifted_ideally(image, sx, sy):
    """(H, W, 3) float: ``image`` sampled at (x + sx, y + sy) by the ideal band-limited
    interpolation (a phase shift of its Fourier transform; periodic, so compare away from edges)."""
    h, w = image.shape[:2]
    phase = np.exp(2j * np.pi * (np.fft.fftfreq(w)[None, :] * sx + np.fft.fftfreq(h)[:, None] * sy))
    return np.stack([np.real(np.fft.ifft2(np.fft.fft2(image[..., c].astype(float)) * phase)) for c in range(3)], -1)


def test_sinc_sampling_keeps_a_real_frames_detail_where_bicubic_loses_it(data_dir):
    frame = read_frames(data_dir, "d3", start=30)[0]
    h, w = frame.shape[:2]
    grid_x, grid_y = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    assert np.array_equal(sample_sinc(frame, grid_x, grid_y), frame)   # its own pixels, bit for bit
    assert np.array_equal(sample_sinc(frame, grid_x[:, :-3] + 3, grid_y[:, :-3]), frame[:, 3:])
    up = upsample2x(frame)
    assert up.shape == (2 * h, 2 * w, 3) and np.array_equal(up[0::2, 0::2], frame)

    face = (slice(150, 350), slice(150, 350))

    def detail(img):   # variance of the Laplacian over the face
        return float(cv2.Laplacian(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), cv2.CV_64F)[face].var())

    ideal = shifted_ideally(frame, 0.5, 0.5)
    got = {k: sample(frame, grid_x + 0.5, grid_y + 0.5, k) for k in ("cubic", "lanczos", "sinc")}
    kept = {k: detail(v) / detail(frame) for k, v in got.items()}
    assert kept["sinc"] > 0.9 and kept["sinc"] > kept["lanczos"] + 0.05 > kept["cubic"] + 0.1, kept
    error = {k: np.sqrt(np.mean((v.astype(float) - ideal)[face] ** 2)) for k, v in got.items()}
    assert error["sinc"] < 0.8 and error["sinc"] < error["cubic"], error


def test_the_upsampling_keeps_the_pixels_and_filters_across_down_and_both_as_three_passes():
    """upsample2x filters the odd rows down in one pass over the even rows (the pixels and those
    interpolated across, interleaved): the same pixels as three separate passes (across, down, and
    down over across), the image's own at the even positions; odd sizes and single rows or columns too."""
    from facesculpt.nodes.renderer.sinc_sampling import TAPS

    a = len(TAPS) // 2 - 1

    def three_passes(image):
        def pass_(img, kernel, anchor):
            return cv2.filter2D(img, -1, kernel, anchor=anchor, borderType=cv2.BORDER_REPLICATE)

        across = pass_(image, TAPS[None, :], (a, 0))
        h, w = image.shape[:2]
        up = np.empty((2 * h, 2 * w, 3), np.uint8)
        up[0::2, 0::2], up[0::2, 1::2] = image, across
        up[1::2, 0::2], up[1::2, 1::2] = pass_(image, TAPS[:, None], (0, a)), pass_(across, TAPS[:, None], (0, a))
        return up

    rng = np.random.default_rng(5)
    for shape in ((37, 29, 3), (1, 17, 3), (13, 1, 3), (2, 2, 3)):
        image = cv2.GaussianBlur(rng.integers(0, 256, shape, np.uint8), (3, 3), 0)
        up = upsample2x(image)
        assert up.shape == (2 * shape[0], 2 * shape[1], 3)
        np.testing.assert_array_equal(up[0::2, 0::2], image)
        np.testing.assert_array_equal(up, three_passes(image))


def test_sinc_sampling_of_a_block_is_that_of_the_whole_frame_and_replicates_edges(data_dir):
    frame = read_frames(data_dir, "d3", start=30)[0]
    h, w = frame.shape[:2]
    grid_x, grid_y = np.meshgrid(np.arange(w, dtype=np.float32) + 0.37, np.arange(h, dtype=np.float32) - 0.21)
    whole = sample_sinc(frame, grid_x, grid_y)
    block = (slice(100, 220), slice(40, 130))   # only the frame around it is upsampled: same pixels
    assert np.array_equal(sample_sinc(frame, grid_x[block], grid_y[block]), whole[block])
    outside_x, outside_y = grid_x[:40, :40] - 60, grid_y[:40, :40] - 60   # all left of and above the frame
    assert np.array_equal(sample_sinc(frame, outside_x, outside_y)[-1, -1], frame[0, 0])
    bicubic = cv2.remap(frame, grid_x - 3.5, grid_y + 2.5, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    assert np.abs(sample_sinc(frame, grid_x - 3.5, grid_y + 2.5).astype(int) - bicubic).mean() < 1.0


def test_sinc_sampling_through_one_upsampling_gives_the_pixels_of_its_own(data_dir):
    """An Upsampled part of the frame serves every sampling whose positions it holds (the drag fill
    and the face), with the pixels each sampling gets alone; one it does not hold, or another
    image's, upsamples its own part as before."""
    frame = read_frames(data_dir, "d3", start=30)[0]
    h, w = frame.shape[:2]
    grid_x, grid_y = np.meshgrid(np.arange(w, dtype=np.float32) + 0.37, np.arange(h, dtype=np.float32) - 0.21)
    shared = Upsampled(frame, (30, 90, 140, 230))
    for block in ((slice(100, 220), slice(40, 130)), (slice(95, 110), slice(31, 60)),   # held
                  (slice(300, 340), slice(200, 260)), (slice(0, 30), slice(0, 30))):    # not held
        alone = sample_sinc(frame, grid_x[block], grid_y[block])
        got = sample_sinc(frame, grid_x[block], grid_y[block], shared)
        assert np.abs(got.astype(int) - alone).max() <= 1 and np.mean(got != alone) < 0.01
    other = frame[::-1].copy()
    block = (slice(100, 220), slice(40, 130))
    assert np.array_equal(sample_sinc(other, grid_x[block], grid_y[block], shared),
                          sample_sinc(other, grid_x[block], grid_y[block]))


def test_one_upsampling_over_the_positions_serves_each_sampling_as_its_own_would(data_dir):
    """upsampled_over takes the bounding box of every positions' set, as sample_sinc grows it: each
    set is sampled through it with the pixels of an upsampling of its own; nothing to read, none."""
    frame = read_frames(data_dir, "d3", start=30)[0]
    rng = np.random.default_rng(3)
    face_x, face_y = np.meshgrid(np.arange(150, 260, dtype=np.float32), np.arange(120, 240, dtype=np.float32))
    face_x += rng.uniform(-3, 3, face_x.shape).astype(np.float32)
    face_y += rng.uniform(-3, 3, face_y.shape).astype(np.float32)
    strip_x = rng.uniform(262, 275, 300).astype(np.float32)   # a drag fill's pixels: one row
    strip_y = rng.uniform(130, 230, 300).astype(np.float32)
    up = upsampled_over(frame, [(face_x, face_y), (strip_x, strip_y), (np.zeros(0, np.float32),) * 2])
    assert (up.x_lo, up.y_lo) == (int(np.floor(min(face_x.min(), strip_x.min()))) - MARGIN_PX,
                                  int(np.floor(min(face_y.min(), strip_y.min()))) - MARGIN_PX)
    assert (up.x_hi, up.y_hi) == (int(np.ceil(max(face_x.max(), strip_x.max()))) + MARGIN_PX + 1,
                                  int(np.ceil(max(face_y.max(), strip_y.max()))) + MARGIN_PX + 1)
    for mx, my in ((face_x, face_y), (strip_x[None, :], strip_y[None, :])):
        alone = sample_sinc(frame, mx, my)
        got = sample_sinc(frame, mx, my, up)
        assert np.abs(got.astype(int) - alone).max() <= 1 and np.mean(got != alone) < 0.01
    assert upsampled_over(frame, [(np.zeros(0, np.float32),) * 2]) is None


def test_the_live_renderers_auto_kernel_is_the_sinc_below_720p():
    assert auto_interpolation("auto", 856, 480) == "sinc"
    assert auto_interpolation("auto", 1280, 720) == auto_interpolation("auto", 1920, 1080) == "cubic"
    assert auto_interpolation("lanczos", 856, 480) == "lanczos"


def test_the_live_renderers_auto_outline_band_is_the_offline_one_below_720p():
    assert auto_outline_band("auto", 856, 480) == OUTLINE_BAND > 0
    assert auto_outline_band("auto", 1280, 720) == auto_outline_band("auto", 3840, 2160) == 0.0
    assert auto_outline_band("0.1", 1920, 1080) == auto_outline_band(0.1, 640, 480) == 0.1   # YAML gives either
    for bad in ("wide", "-0.05", 0.8, "nan", None):
        with pytest.raises(ValueError, match="outline_band must be auto or a share"):
            auto_outline_band(bad, 856, 480)


def test_the_live_renderers_auto_mesh_follows_the_faces_size_from_720p():
    """The compositor's default below 720p; from there on as fine as the face's size needs."""
    assert auto_subdivision("auto", 856, 480) == (None, MAX_FINE_EDGE_PX)
    assert auto_subdivision("auto", 1280, 720) == (None, AUTO_MAX_FINE_EDGE_PX)
    assert auto_subdivision(2, 1920, 1080) == auto_subdivision("2", 640, 480) == (2, None)   # YAML gives either
    for bad in ("4", "-1", "fine", 1.5):
        with pytest.raises(ValueError, match="subdivision must be auto or 0 to 3"):
            auto_subdivision(bad, 856, 480)


# -- fills ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def background_patch(data_dir):
    """A real, face-free 160x160 patch of s18 (plants and floor, left of the person)."""
    frame = read_frames(data_dir, "s18")[0]
    return np.ascontiguousarray(frame[200:360, 60:220])


def band_hole(shape, width):
    """A curved band ``width`` px wide across the patch, like the strip a narrowing cheek leaves."""
    h, w = shape
    yy, xx = np.mgrid[:h, :w]
    centre = w / 2 + 20 * np.sin(yy / h * np.pi)
    return (np.abs(xx - centre) < width / 2) & (yy > 10) & (yy < h - 10)


@pytest.mark.parametrize("fill", [fill_pushpull, fill_telea])
@pytest.mark.parametrize("width", [4, 10])
def test_fill_recovers_a_real_background_band(background_patch, fill, width):
    hole = band_hole(background_patch.shape[:2], width)
    out = fill(background_patch, hole, ~hole)
    assert np.array_equal(out[~hole], background_patch[~hole])  # only the hole is written
    truth = background_patch[hole].astype(float)
    err = np.abs(out[hole].astype(float) - truth).mean()
    # Far better than the plain guess (the mean colour of the known pixels), and close to truth.
    naive = np.abs(background_patch[~hole].mean(axis=0) - truth).mean()
    assert err < 0.4 * naive
    assert err < 12.0


def test_pushpull_reads_only_sources(background_patch):
    hole = band_hole(background_patch.shape[:2], 8)
    ignored = np.zeros_like(hole)
    ignored[:, :40] = True                         # neither source nor hole
    source = ~hole & ~ignored
    a = fill_pushpull(background_patch, hole, source)
    scrambled = background_patch.copy()
    scrambled[ignored] = 255 - scrambled[ignored]
    b = fill_pushpull(scrambled, hole, source)
    assert np.array_equal(a[hole], b[hole])
    assert np.array_equal(b[ignored], scrambled[ignored])  # ignored pixels are not written


def test_fills_need_a_source():
    img = np.zeros((20, 20, 3), np.uint8)
    hole = np.zeros((20, 20), bool)
    hole[5:10, 5:10] = True
    with pytest.raises(ValueError, match="no source"):
        fill_pushpull(img, hole, np.zeros_like(hole))
    with pytest.raises(ValueError, match="no source"):
        fill_telea(img, hole, np.zeros_like(hole))
    with pytest.raises(ValueError, match="unknown inpaint"):
        fill_by_parts(img, hole, ~hole, method="navier")


@pytest.mark.parametrize("method", ["pushpull", "telea"])
def test_fill_by_parts_fills_each_part_on_its_own_box(background_patch, method):
    """Two bands far apart (one per cheek): each is filled on its own box plus the margin, exactly
    as the fill of that box alone; nothing else changes; in place writes into the given frame."""
    frame = np.zeros((400, 600, 3), np.uint8)
    frame[100:260, 40:200] = background_patch
    frame[180:340, 400:560] = background_patch[::-1]
    hole = np.zeros((400, 600), bool)
    hole[100:260, 40:200] = band_hole(background_patch.shape[:2], 8)
    hole[180:340, 400:560] = band_hole(background_patch.shape[:2], 12)
    out = fill_by_parts(frame, hole, ~hole, method=method, margin=8)
    assert np.array_equal(out[~hole], frame[~hole])
    for part in (slice(0, 300), slice(300, 600)):
        part_hole = np.zeros_like(hole)
        part_hole[:, part] = hole[:, part]
        x, y, w, h = cv2.boundingRect(part_hole.astype(np.uint8))
        crop = (slice(y - 8, y + h + 8), slice(x - 8, x + w + 8))
        fill = fill_pushpull if method == "pushpull" else fill_telea
        direct = fill(np.ascontiguousarray(frame[crop]), hole[crop], ~hole[crop])
        assert np.array_equal(out[crop], direct)
    same = frame.copy()
    assert fill_by_parts(same, hole, ~hole, method=method, margin=8, in_place=True) is same
    assert np.array_equal(same, out)


def test_parts_whose_boxes_overlap_share_one_box():
    """Specks beside a band go on the band's box, grown to hold them whole; a part far from both
    keeps its own; every box is cut to the image."""
    rects = [(20, 20, 10, 40), (33, 62, 3, 2), (5, 50, 2, 2), (130, 5, 5, 5), (110, 80, 6, 6)]
    boxes = sorted(part_boxes(rects, 8, 150, 100))
    assert boxes == [(0, 12, 44, 72), (102, 72, 124, 94), (122, 0, 143, 18)], boxes
    assert part_boxes([], 8, 150, 100) == []


def test_uncovered_mask_is_the_dilated_difference_without_slivers():
    original = np.zeros((60, 60), np.uint8)
    original[10:50, 10:50] = 1
    deformed = np.zeros_like(original)
    deformed[10:50, 18:50] = 1          # the left side moved in by 8 px
    deformed[10:50, 10:11] = 0
    mask = uncovered_mask(original, deformed, dilate_px=2)
    assert mask[20:40, 10:18].all()
    assert not mask[20:40, 21:].any()   # grows 2 px into the moved face, no further
    assert mask[20:40, 8].all() and not mask[20:40, 7].any()  # and 2 px past the old outline
    only_sliver = original.copy()
    only_sliver[10:50, 49] = 0          # a one-pixel sliver: rasterisation noise, not a hole
    assert not uncovered_mask(original, only_sliver, 2).any()


# -- camera -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def head(data_dir):
    from facesculpt.nodes.fitter import load_model

    model = load_model("sfm")
    return model.mean.astype(np.float64), dict(zip(model.landmark_names, model.landmark_vertices))


def rotation(yaw_deg, pitch_deg):
    return cv2.Rodrigues(np.array([pitch_deg, yaw_deg, 0.0]) * np.pi / 180)[0]


@pytest.mark.parametrize("kind", ["perspective", "orthographic-opencv", "orthographic-opengl"])
def test_projection_is_recovered_and_depth_orders_nose_before_cheeks(head, kind):
    mean, names = head
    # Model space: y up, z toward the viewer. Flip to OpenCV's camera (y down, z away).
    flip = np.diag([1.0, -1.0, -1.0])
    R = flip @ rotation(25, 10)
    if kind == "perspective":
        K = np.array([[900.0, 0, 428], [0, 900.0, 240], [0, 0, 1]])
        X = mean @ R.T + [30.0, -10.0, 600.0]
        p = X @ K.T
        px = p[:, :2] / p[:, 2:]
    elif kind == "orthographic-opencv":  # pixel-scale camera space, x right, y down, z away
        X = 1.7 * mean @ R.T + [420.0, 250.0, 0.0]
        px = X[:, :2]
    else:                                # OpenGL-style: y up, z toward the viewer; image y flipped
        X = 1.7 * mean @ rotation(25, 10).T
        px = np.column_stack([X[:, 0] + 420.0, 250.0 - X[:, 1]])
    P = estimate_projection(X, px)
    got, depth = project(P, X)
    assert np.abs(got - px).max() < 1e-6
    nose, cheeks = names["nose_tip"], [names["left_cheek"], names["right_cheek"]]
    assert depth[nose] < depth[cheeks].min()
    # Moving the nose 15 mm toward the camera (camera space: -z for OpenCV, +z for OpenGL)
    # makes it nearer still.
    toward = np.array([0.0, 0.0, 1.0 if kind == "orthographic-opengl" else -1.0])
    _, d2 = project(P, X + 15 * toward)
    assert d2[nose] < depth[nose]


def test_projection_needs_a_real_camera():
    with pytest.raises(ValueError, match="at least 6"):
        estimate_projection(np.zeros((5, 3)), np.zeros((5, 2)))
    flat = np.random.default_rng(0).normal(size=(50, 3))
    flat[:, 2] = 0
    with pytest.raises(ValueError, match="degenerate"):
        estimate_projection(flat, flat[:, :2])


# -- mesh -------------------------------------------------------------------------------------
def test_close_holes_leaves_only_the_outline(data_dir):
    from facesculpt.nodes.fitter import load_model

    tri = load_model("sfm").triangles
    loops = boundary_loops(tri)
    assert [len(loop) for loop in loops] == [112, 48]   # the outline and the mouth
    closed = close_holes(tri)
    assert len(closed) == len(tri) + 48 - 2
    assert [len(loop) for loop in boundary_loops(closed)] == [112]
    assert close_holes(closed).shape == closed.shape


# -- subdivision ------------------------------------------------------------------------------
def test_vertex_rings_reach_as_many_edges_as_asked():
    """A strip of triangles over vertices 0..9 in a row (and 10: in no triangle)."""
    strip = np.array([(i, i + 1, i + 2) for i in range(8)])
    for rings, reach in ((1, set(range(2, 7))), (2, set(range(0, 9)))):   # a triangle spans two steps
        near = vertex_rings(strip, 11, rings) @ np.eye(11, dtype=np.float32)[4] > 0
        assert set(np.flatnonzero(near)) == reach
    alone = vertex_rings(strip, 11, 2) @ np.eye(11, dtype=np.float32)[10] > 0
    assert not alone.any()   # a vertex of no triangle is near nothing


def test_point_bounds_are_the_per_coordinate_extremes():
    points = np.random.default_rng(0).normal(size=(500, 3)) * [1, 10, 100]
    lo, hi = point_bounds(points)
    assert np.array_equal(lo, points.min(axis=0)) and np.array_equal(hi, points.max(axis=0))
    assert [b.tolist() for b in point_bounds(np.array([[3, -1]]))] == [[3, -1], [3, -1]]


def test_loop_subdivision_is_affine_and_keeps_a_plane_planar(data_dir):
    from facesculpt.nodes.fitter import facemesh_model

    model = facemesh_model()
    tri = close_holes(model.triangles)
    V = len(model.mean)
    for levels in (1, 2):
        S, fine = loop_subdivision(tri, V, levels)
        assert S.shape[1] == V and len(fine) == len(tri) * 4 ** levels
        assert fine.max() == S.shape[0] - 1
        assert np.abs(np.asarray(S.sum(axis=1)).ravel() - 1.0).max() < 1e-5   # rows sum to 1
        assert S.min() >= 0.0                                                   # convex combinations
        # One outline still (the holes are closed), four times (per level) as many vertices on it.
        assert [len(loop) for loop in boundary_loops(fine)] == [len(boundary_loops(tri)[0]) * 2 ** levels]
        # The face mesh's vertices put on a tilted plane stay on it; a translation translates.
        rng = np.random.default_rng(levels)
        xy = model.mean[:, :2].astype(np.float64)
        plane = np.column_stack([xy, 0.3 * xy[:, 0] - 0.7 * xy[:, 1] + 5.0])
        finer = S @ plane
        assert np.abs(finer[:, 2] - (0.3 * finer[:, 0] - 0.7 * finer[:, 1] + 5.0)).max() < 1e-3
        shift = rng.normal(size=3)
        assert np.allclose(S @ (plane + shift), finer + shift, atol=1e-3)
        # Zero stays exactly zero: an unmoved vertex neighbourhood keeps an offset of 0.
        offset = np.zeros((V, 2), np.float32)
        offset[0] = 1.0
        moved = S @ offset
        assert (moved == 0).all(axis=1).sum() > 0.9 * S.shape[0]


def test_loop_subdivision_smooths_a_polygon_outline():
    """A coarse disc (a fan around a centre): its outline's corners turn 45 degrees each; after two
    levels the outline is the cubic B-spline of the octagon, turning about 11 degrees per vertex."""
    n = 8
    angles = np.arange(n) * 2 * np.pi / n
    points = np.vstack([[0.0, 0.0], np.column_stack([np.cos(angles), np.sin(angles)])])
    tri = np.array([(0, 1 + i, 1 + (i + 1) % n) for i in range(n)])
    S, fine = loop_subdivision(tri, len(points), 2)
    loop = boundary_loops(fine)[0]
    outline = S @ points
    edges = np.diff(outline[np.r_[loop, loop[0]]], axis=0)
    heading = np.arctan2(edges[:, 1], edges[:, 0])
    turn = np.degrees(np.abs(np.angle(np.exp(1j * np.diff(np.r_[heading, heading[0]])))))
    assert len(loop) == 4 * n
    assert turn.max() < 15.0 and abs(turn.sum() - 360.0) < 1e-6
    # The boundary rule: the outline depends on outline vertices only (moving the centre moves
    # no fine outline vertex).
    lifted = points.copy()
    lifted[0] = [0.3, -0.2]
    assert np.allclose((S @ lifted)[loop], outline[loop])


def test_subdivision_levels_and_errors():
    assert levels_for(898) == 2 and levels_for(6782) == 0 and levels_for(3000) == 1
    # by the face's size: the fewest levels, at least one, that make the fine edges 8 px or shorter
    assert levels_for(898, 12.0, 8.0) == 1 and levels_for(898, 4.0, 8.0) == 1 and levels_for(898, 20.0, 8.0) == 2
    assert levels_for(898, 100.0, 8.0) == 2 and levels_for(6782, 20.0, 8.0) == 0   # within the budget
    # near the threshold the last frame's levels stay (no switching back and forth)
    assert levels_for(898, 17.0, 8.0) == 2 and levels_for(898, 17.0, 8.0, current=1) == 1
    assert levels_for(898, 19.0, 8.0, current=1) == 2
    assert levels_for(898, 14.0, 8.0, current=2) == 2 and levels_for(898, 13.0, 8.0, current=2) == 1
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    assert median_edge_px(square, np.array([[0, 1, 2], [0, 2, 3]])) == 10.0
    with pytest.raises(ValueError, match="levels"):
        loop_subdivision(np.array([[0, 1, 2]]), 3, -1)
    with pytest.raises(ValueError, match="indices"):
        loop_subdivision(np.array([[0, 1, 5]]), 3, 1)


# -- video ------------------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".mp4", ".avi"])
def test_video_output_writes_every_frame(data_dir, tmp_path, suffix):
    frames = read_frames(data_dir, "d0", count=6)
    path = tmp_path / f"out{suffix}"
    with VideoOutput(path, fps=25.0) as video:
        for f in frames:
            video.write(f)
        with pytest.raises(ValueError, match="512x512"):
            video.write(frames[0][:100])
    cap = cv2.VideoCapture(str(path))
    back = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        back.append(f)
    assert len(back) == len(frames)
    for a, b in zip(frames, back):
        mse = np.mean((a.astype(float) - b.astype(float)) ** 2)
        assert 10 * np.log10(255 ** 2 / mse) > 28
    with pytest.raises(ValueError, match="suffix"):
        VideoOutput(tmp_path / "out.gif")
