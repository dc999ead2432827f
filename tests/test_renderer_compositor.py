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

from benchmarks.renderer_scene import (
    dilate,
    issue_edit,
    place_fitted,
    place_marked,
    plane_mesh,
    rasterize_region,
    read_frames,
)
from facesculpt.geometry import merge_deformation
from facesculpt.nodes.renderer import Compositor
from facesculpt.nodes.renderer.gl_context import create_headless_context
from facesculpt.nodes.renderer.warp import sample as sample_frame

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
    """Lanczos-4 samples (OpenCV) (N, 3) float of ``image`` at pixel positions ``px`` (N, 2)."""
    m = np.asarray(px, np.float32).reshape(-1, 1, 2)
    return cv2.remap(image, m[..., 0], m[..., 1], cv2.INTER_LANCZOS4).reshape(-1, 3).astype(np.float64)


def test_zero_deformation_leaves_every_pixel_bit_identical(gl, scene):
    video, frame, pose, _ = scene
    original = frame.copy()
    H, W = frame.shape[:2]
    comp = Compositor(W, H, ctx=gl)
    out = comp.render(frame, pose.fitted, pose.projected, pose.triangles, pose.fitted.copy())
    assert out is not frame and np.array_equal(out, frame)
    assert comp.box is None  # nothing moved: nothing re-rendered, inpainted or blended
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
    regions = comp.full_frame_regions()
    box, band = comp.box, comp.band_px(pose.projected)
    # where the drawn (subdivided) surface puts the vertices, deformed and in the input
    surface_dst, surface_src = comp.drawn_px(deformed_px), comp.drawn_px(pose.projected)
    comp.release()
    original = rasterize_region(pose.projected, pose.triangles, (H, W))
    moved = rasterize_region(deformed_px, pose.triangles, (H, W))
    # The GL coverage (the subdivided mesh, in the work box) is the independently rasterised
    # silhouette there; only covered pixels are re-rendered; every pixel neither re-rendered
    # nor inpainted is the input's, bit for bit.
    inside = np.zeros((H, W), bool)
    inside[box[1]:box[3], box[0]:box[2]] = True
    drawn, expected = regions["deformed"] & inside, moved & inside
    assert (drawn & expected).sum() / (drawn | expected).sum() > 0.95
    # (and the band past both outlines the motion is carried over, fading out: outline_band)
    assert 4 <= band <= 30
    assert regions["changed"].sum() > 1000
    assert not (regions["changed"] & ~dilate(regions["deformed"] | original, band + 1)).any()
    kept = ~(regions["changed"] | regions["inpainted"])
    assert np.array_equal(out[kept], frame[kept])

    # No background distortion: bit-identical outside the union of both regions and the band.
    outside = ~dilate(original | moved, band + 2)
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
    # tip (always visible here) the output where the drawn surface puts a vertex is the input
    # where it put it before the edit.
    near_nose = np.linalg.norm(pose.rest - pose.rest[pose.landmarks["nose_tip"]], axis=1) < 10.0
    mapped = np.abs(sample(out, surface_dst[near_nose]) - sample(frame, surface_src[near_nose])).mean(axis=1)
    assert np.median(mapped) <= 2.0
    if video == "s18":  # the nose moves ~4 px in the image there: the unmoved texture would not match
        unmoved = np.abs(sample(out, surface_dst[near_nose]) - sample(frame, surface_dst[near_nose])).mean(axis=1)
        assert np.median(unmoved) >= 4 * max(np.median(mapped), 0.5)


def test_the_work_box_holds_everything_the_edit_changes(gl, data_dir, sfm, monkeypatch):
    """The work box's background (the larger of the fill's context and the carried band, not their
    sum): a box with far more background around the face renders the same frame."""
    import facesculpt.nodes.renderer.compositor as compositor

    frame = read_frames(data_dir, "s18")[0]
    pose = place_marked(sfm, "s18")
    deformed = merge_deformation(pose.fitted, pose.R, pose.scale, issue_edit(pose))
    H, W = frame.shape[:2]
    outs, boxes = [], []
    for context in (compositor.FILL_CONTEXT_PX, compositor.FILL_CONTEXT_PX + 40):
        monkeypatch.setattr(compositor, "FILL_CONTEXT_PX", context)
        comp = Compositor(W, H, ctx=gl)
        outs.append(comp.render(frame, pose.fitted, pose.projected, pose.triangles, deformed).astype(int))
        boxes.append(comp.box)
        comp.release()
    (x0, y0, x1, y1), (X0, Y0, X1, Y1) = boxes
    assert (X1 - X0) * (Y1 - Y0) > 1.3 * (x1 - x0) * (y1 - y0)
    differ = np.abs(outs[0] - outs[1]).max(axis=2)
    assert differ.max() <= 2 and np.mean(differ > 0) < 1e-4, (differ.max(), np.mean(differ > 0))


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
    with pytest.raises(ValueError, match="inpaint must be one of"):
        Compositor(W, H, ctx=gl, inpaint="navier")
    # After the errors it still renders correctly.
    assert np.array_equal(comp.render(frame, X, px, T, X), frame)
    comp.release()


# -- the warp itself, on a known mesh ------------------------------------------------------------


def laplacian_variance(image: np.ndarray, mask: np.ndarray) -> float:
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return float(cv2.Laplacian(grey, cv2.CV_64F, ksize=1)[mask].var())


@pytest.mark.parametrize("shift", [(3.0, -2.0), (0.4, 0.3), (-1.5, 0.5)], ids=str)
def test_translated_plane_is_the_frame_warped_once_at_full_quality(gl, data_dir, shift):
    """A flat mesh over the face of a real frame, moved by ``shift`` px: inside it, the output is
    the input sampled at the translated positions by the default kernel (the sinc), as sharp as
    that and close to the bicubic's geometry; an integer shift moves the pixels exactly."""
    frame = read_frames(data_dir, "s18")[0]
    H, W = frame.shape[:2]
    vertices, projected, triangles = plane_mesh((530, 200), 160)
    moved = vertices + [shift[0], shift[1], 0.0]
    comp = Compositor(W, H, ctx=gl)
    out = comp.render(frame, vertices, projected, triangles, moved)
    feather = comp.feather_width(projected)
    comp.release()
    yy, xx = np.mgrid[:H, :W].astype(np.float32)
    expected = sample_frame(frame, xx - np.float32(shift[0]), yy - np.float32(shift[1]), "sinc")
    bicubic = cv2.remap(frame, xx - np.float32(shift[0]), yy - np.float32(shift[1]), cv2.INTER_CUBIC,
                        borderMode=cv2.BORDER_REPLICATE)
    inner = 80 - feather - 4  # inside both squares, past the soft edge
    inside = (np.abs(xx - 530 - shift[0]) < inner) & (np.abs(yy - 200 - shift[1]) < inner)
    inside &= (np.abs(xx - 530) < inner) & (np.abs(yy - 200) < inner)
    diff = np.abs(out[inside].astype(int) - expected[inside])
    if float(shift[0]).is_integer() and float(shift[1]).is_integer():
        assert np.array_equal(out[inside], expected[inside])
        assert np.array_equal(out[inside], np.roll(frame, (int(shift[1]), int(shift[0])), axis=(0, 1))[inside])
    assert diff.max() <= 2 and diff.mean() < 0.2
    assert np.abs(out[inside].astype(int) - bicubic[inside]).mean() < 1.5   # the same positions
    assert laplacian_variance(out, inside) / laplacian_variance(expected, inside) >= 0.95
    assert laplacian_variance(out, inside) / laplacian_variance(frame, inside) >= 0.9  # the kernel keeps the detail
    # Far from the square nothing changed.
    far = (np.abs(xx - 530) > 100) | (np.abs(yy - 200) > 100)
    assert np.array_equal(out[far], frame[far])


def test_the_edit_moves_a_real_outline_that_lies_past_the_fitted_one(gl):
    """Registration error: the fit's outline 6 px inside the true one. Pulling the lower face down
    12 px moves the true lower edge with it as far as the outline band reaches; without the band
    the fitted outline moves and the 6 px rim of the true face below it stays behind."""
    H, W, top, bottom = 480, 640, 240 - 86, 240 + 86   # the true face: rows top..bottom, 172 px wide
    frame = np.full((H, W, 3), 40, np.uint8)
    frame[top:bottom + 1, 320 - 86:320 + 87] = 200
    vertices, projected, triangles = plane_mesh((320, 240), 160)   # the fit: 6 px inside on every side
    ramp = np.clip((vertices[:, 1] - 240) / 80, 0, 1)            # lower half pulled down, smoothly
    moved = vertices + np.column_stack([0 * ramp, 12 * ramp, 0 * ramp])
    edges = {}
    for band in (0.0, 0.05):
        with Compositor(W, H, ctx=gl, outline_band=band) as comp:
            out = comp.render(frame, vertices, projected, triangles, moved)
        column = out[:, 300:341, 0].astype(int).mean(axis=1)
        edges[band] = int(np.flatnonzero(column > 120).max())    # the lowest bright row
        assert np.array_equal(out[:top - 30], frame[:top - 30])  # far above the edit nothing moves
    assert abs(edges[0.0] - (bottom + 6)) <= 2, edges     # the fitted outline moved 12, the rim stayed
    # the true outline moves with the face, most of the way: the band fades out over 8 px here
    assert bottom + 7 <= edges[0.05] <= bottom + 13 and edges[0.05] >= edges[0.0] + 3, edges


def test_a_narrowed_outline_is_as_sharp_as_a_filmed_one(gl):
    """Pushing the right side of a face in 12 px: where the new outline meets the background it
    uncovered, the face is opaque 2 px inside it (a filmed silhouette's anti-aliasing), not
    feathered over the fill for the seam's width, which left a pale band along a narrowed jaw."""
    from facesculpt.nodes.renderer.compositor import SILHOUETTE_FEATHER_PX

    H, W = 480, 640
    vertices, projected, triangles = plane_mesh((320, 240), 160)
    frame = np.full((H, W, 3), 40, np.uint8)
    frame[160:321, 240:401] = 200                                 # the true face: the fit's square
    ramp = np.clip((vertices[:, 0] - 320) / 80, 0, 1)             # the right half pushed in
    moved = vertices - np.column_stack([12 * ramp, 0 * ramp, 0 * ramp])
    with Compositor(W, H, ctx=gl) as comp:
        out = comp.render(frame, vertices, projected, triangles, moved)
        assert comp.feather_width(projected) > SILHOUETTE_FEATHER_PX + 0.5  # the seam's feather is wider
    row = out[200:281, :, 0].astype(int)
    edge = 400 - 12
    assert (row[:, edge - 12:edge - 1] >= 190).all(), row[0, edge - 14:edge + 4]
    assert (row[:, edge + 3:edge + 12] <= 60).all(), row[0, edge - 4:edge + 14]   # the background it uncovered


def test_carry_past_outline_fades_the_band_out_and_fills_the_gap_unfaded():
    """The face (a disc moving 5 px right) shrank from a larger disc: past the old outline the
    offsets fade from almost 5 px to nothing at the reach; the gap between the outlines takes the
    face's offset whole when asked (the drag fill), else stays uncovered."""
    from facesculpt.nodes.renderer.motion_extension import carry_past_outline
    from facesculpt.nodes.renderer.source_map import UNCOVERED

    yy, xx = np.mgrid[:101, :101]
    r = np.hypot(xx - 50.0, yy - 50.0)
    offsets = np.full((101, 101, 2), UNCOVERED, np.float32)
    offsets[r <= 20] = (5.0, 0.0)
    outline = (r <= 30).astype(np.uint8)                 # the old face and the new together
    gap = (r > 20.5) & (r < 29.5)
    reach = 10.0
    for with_gap in (False, True):
        out = carry_past_outline(offsets, outline, reach, gap if with_gap else None)
        assert np.array_equal(out[r <= 20], offsets[r <= 20])
        if with_gap:
            assert np.allclose(out[gap], (5.0, 0.0))
        else:
            assert (out[gap][:, 0] == UNCOVERED).all()
        assert (out[r > 30 + reach + 1.5][:, 0] == UNCOVERED).all()   # beyond reach: not moved
        ring = [out[(r > 30 + d - 0.5) & (r <= 30 + d + 0.5)][:, 0] for d in (1, 4, 7)]
        means = [float(v[v < 0.5 * UNCOVERED].mean()) for v in ring]
        assert 4.5 < means[0] <= 5.0 and means[0] > means[1] > means[2] > 0.0, means
        assert np.allclose(out[(r > 30.5) & (r < 39.5)][:, 1], 0.0)   # the motion's direction kept


# -- smooth outlines -----------------------------------------------------------------------------
def outline_turning(region: np.ndarray, centre, radius: float, chord: int = 6) -> float:
    """The largest turn (degrees) between consecutive ``chord``-px chords of the outline of
    ``region`` (H, W) bool, smoothed along the contour (sigma 1.5 px, the pixel staircase),
    within ``radius`` px of ``centre`` (x, y)."""
    contours, _ = cv2.findContours(region.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    c = max(contours, key=len)[:, 0, :].astype(float)
    k = np.arange(-5, 6)
    w = np.exp(-0.5 * (k / 1.5) ** 2)
    w /= w.sum()
    smooth = sum(wi * np.roll(c, -ki, axis=0) for ki, wi in zip(k, w))
    step = np.roll(smooth, -chord, axis=0) - smooth
    angle = np.arctan2(step[:, 1], step[:, 0])
    turn = np.abs(np.angle(np.exp(1j * (np.roll(angle, -chord) - angle))))
    near = np.linalg.norm(smooth - np.asarray(centre), axis=1) < radius
    assert near.sum() > 50
    return float(np.degrees(turn[near]).max())


#: The chin pulled by its vertex alone (the shipped `chin` preset moves a patch of skin with it).
ONE_VERTEX_CHIN = {"format": "facesculpt-deformer-preset", "version": 1, "units": "mm", "static": [],
                   "edits": [{"handles": [{"landmark": "chin", "offset": [0.0, -10.0, 4.0]}],
                              "roi": {"radius": 45.0, "metric": "geodesic"}}]}


def test_chin_preset_outline_is_a_smooth_curve_not_a_polygon(gl, data_dir, detector):
    """A chin pull by one vertex on the 468-vertex face mesh: drawn from the mesh as it is, the
    new outline is a polygon with corners at the vertices; subdivided (the default), it turns
    gradually."""
    from facesculpt.nodes.deformer import EditStack
    from facesculpt.nodes.fitter import facemesh_model

    frame = read_frames(data_dir, "d0")[0]
    H, W = frame.shape[:2]
    pose = place_fitted(facemesh_model(), frame, detector)
    # a single-vertex handle (grip 0): the sharpest corner the mesh can make, which the subdivision must round
    stack = EditStack(pose.rest, pose.triangles, list(pose.landmarks), list(pose.landmarks.values()), grip=0.0,
                      min_solve_vertices=0)   # the mesh as it is: this is the compositor's test
    stack.apply_preset(ONE_VERTEX_CHIN)
    deformed = merge_deformation(pose.fitted, pose.R, pose.scale, stack.solve())
    width = float(np.ptp(pose.projected[:, 0]))
    turning = {}
    for levels in (0, None):
        comp = Compositor(W, H, ctx=gl, subdivision=levels)
        comp.render(frame, pose.fitted, pose.projected, pose.triangles, deformed)
        chin = comp.deformed_px[pose.landmarks["chin"]]
        assert chin[1] > pose.projected[pose.landmarks["chin"], 1] + 5  # the chin did move down
        turning[levels] = outline_turning(comp.full_frame_regions()["deformed"], chin, 0.25 * width)
        comp.release()
    assert turning[0] > 30.0             # the polygon's corners
    assert turning[None] < 22.0          # a curve
    assert turning[None] < 0.55 * turning[0]


def test_the_mesh_follows_the_faces_size_and_renders_as_a_fixed_one(gl, data_dir, detector):
    """With an edge limit, a large face gets two levels of subdivision and a small one one level,
    per frame; each frame is the one the compositor gives with that level fixed, and a face that
    shrinks and grows again is drawn as before (the meshes and GL buffers are reused)."""
    from facesculpt.app.pipeline import read_preset
    from facesculpt.nodes.deformer import EditStack
    from facesculpt.nodes.fitter import facemesh_model

    frame = read_frames(data_dir, "d0")[0]
    H, W = frame.shape[:2]
    pose = place_fitted(facemesh_model(), frame, detector)
    stack = EditStack(pose.rest, pose.triangles, list(pose.landmarks), list(pose.landmarks.values()))
    stack.apply_preset(read_preset("chin"))
    deformed = merge_deformation(pose.fitted, pose.R, pose.scale, stack.solve())
    big_frame = cv2.resize(frame, (2 * W, 2 * H), interpolation=cv2.INTER_CUBIC)
    # orthographic camera space is in pixels: the face twice as large is every coordinate doubled
    small = (pose.fitted, pose.projected, deformed)
    big = tuple(2.0 * a for a in small)
    comp = Compositor(2 * W, 2 * H, ctx=gl, max_fine_edge_px=8.0)
    outs, levels = [], []
    for face in (big, small, big):
        outs.append(comp.render(big_frame, face[0], face[1], pose.triangles, face[2]))
        levels.append(comp.meshes.last_levels)
    comp.release()
    assert levels == [2, 1, 2]
    np.testing.assert_array_equal(outs[2], outs[0])
    for out, face, fixed in ((outs[0], big, 2), (outs[1], small, 1)):
        comp = Compositor(2 * W, 2 * H, ctx=gl, subdivision=fixed)
        np.testing.assert_array_equal(out, comp.render(big_frame, face[0], face[1], pose.triangles, face[2]))
        comp.release()
    assert not np.array_equal(outs[0], big_frame)   # the chin moved
