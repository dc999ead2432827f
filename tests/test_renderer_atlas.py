"""The face's texture memory (issue 16): the UV atlas learns a known texture from synthetic views
(rendered by the realism benchmark's reference rasteriser), ignores what is kept in front of the
face, compensates a lighting change, starts afresh on another face; in the compositor it gives a
surface the current view hides its colours; ``process --save-texture`` writes it. Real EGL
context, real frames."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from benchmarks.realism.raster import project as reference_project
from benchmarks.realism.raster import project_pixels, render_textured
from facesculpt.nodes.renderer import Compositor
from facesculpt.nodes.renderer.atlas_raster import AtlasRasterizer, vertex_frontality
from facesculpt.nodes.renderer.camera import estimate_projection
from facesculpt.nodes.renderer.gl_context import create_headless_context
from facesculpt.nodes.renderer.texture_atlas import TextureAtlas, uv_layout

REPO = Path(__file__).resolve().parent.parent
W, H, S, T = 320, 240, 128, 256
K = np.array([[300.0, 0, W / 2], [0, 300.0, H / 2], [0, 0, 1]])


def bump(n: int = 33):
    """A face-sized height field (model mm: x right, y up, z toward the viewer) with a tall bump
    (a nose) in the middle: vertices (V, 3), triangles (T, 3), uv (V, 2) in [0, 1] (v down)."""
    g = np.linspace(-1, 1, n)
    xx, yy = np.meshgrid(g, g)
    zz = 45 * np.exp(-(xx ** 2 + yy ** 2) / 0.12)
    M = np.column_stack([60 * xx.ravel(), -60 * yy.ravel(), zz.ravel()])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    tri = np.concatenate([np.column_stack([a, c, b]), np.column_stack([b, c, d])])
    uv = np.column_stack([(xx.ravel() + 1) / 2, (yy.ravel() + 1) / 2]).astype(np.float32)
    return M, tri, uv


MESH, TRI, UV = bump()
TEXTURE = cv2.resize(np.random.default_rng(0).integers(0, 255, (12, 12, 3), dtype=np.uint8), (T, T),
                     interpolation=cv2.INTER_CUBIC)
BACKGROUND = np.full((H, W, 3), 40, np.uint8)


def pose(M: np.ndarray, yaw: float) -> np.ndarray:
    a = np.radians(yaw)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]) @ np.diag([1.0, -1, -1])
    return M @ R.T + [0.0, 0.0, 330.0]


def view(yaw: float, gain: float = 1.0):
    """(frame (H, W, 3) uint8, camera-space vertices (V, 3), their pixels (V, 2), OpenCV centres)."""
    X = pose(MESH, yaw)
    img = render_textured(K, X, TRI, UV * T, np.ones(len(X)), TEXTURE.astype(np.float32) * gain, BACKGROUND)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), X, project_pixels(K, X)


@pytest.fixture(scope="module")
def gl():
    ctx = create_headless_context()
    raster = AtlasRasterizer(ctx, S, W, H)
    yield raster
    raster.release()
    ctx.release()


def take(atlas: TextureAtlas, raster: AtlasRasterizer, yaw: float, gain: float = 1.0, keep_mask=None):
    frame, X, px = view(yaw, gain)
    texel_px, quality = raster.observe(X, px, TRI, UV, estimate_projection(X, px))
    atlas.update(frame, texel_px, quality, keep_mask)
    return frame, texel_px, quality


TRUTH = cv2.resize(TEXTURE, (S, S), interpolation=cv2.INTER_AREA).astype(np.float32)
INNER = np.zeros((S, S), bool)
INNER[8:-8, 8:-8] = True


def atlas_error(atlas: TextureAtlas) -> float:
    """Mean absolute error (0..255) of the atlas against the texture over the inner texels (a texel
    never seen counts with its black)."""
    return float(np.abs(atlas.colour - TRUTH).mean(axis=2)[INNER].mean())


def test_the_atlas_learns_a_known_texture_as_views_accumulate(gl):
    atlas = TextureAtlas(S)
    errors = []
    for yaw in (55, -55, 0):
        take(atlas, gl, yaw)
        errors.append(atlas_error(atlas))
    # a side turned away is learned when it turns toward the camera
    assert errors[0] > errors[1] > errors[2] * 0.98, errors
    assert errors[0] > 3 * errors[2], errors
    assert errors[2] < 6.0, errors
    known = atlas.weight > 0
    assert known[INNER].mean() > 0.99


def test_pixels_kept_in_front_of_the_face_are_not_learned(gl):
    atlas = TextureAtlas(S)
    frame, X, px = view(0)
    hand = np.zeros((H, W), bool)
    hand[:, : W // 2] = True
    frame[hand] = (0, 0, 255)   # a red hand over the left half of the picture
    texel_px, quality = gl.observe(X, px, TRI, UV, estimate_projection(X, px))
    took = atlas.update(frame, texel_px, quality, keep_mask=hand)
    assert took > 0
    behind = np.nan_to_num(texel_px[..., 0], nan=W) < W // 2 - 2
    assert behind.sum() > 1000
    assert (atlas.weight[behind] == 0).all()
    red = (atlas.colour[..., 2] > 200) & (atlas.colour[..., 0] < 60) & (atlas.colour[..., 1] < 60)
    assert not red.any()


def test_colour_correction_compensates_a_global_gain_change(gl):
    atlas = TextureAtlas(S)
    take(atlas, gl, 0)
    before = atlas.colour.copy()
    frame, _, _ = take(atlas, gl, 10, gain=0.7)
    np.testing.assert_allclose(atlas.gain, 1 / 0.7, rtol=0.05)
    seen = atlas.weight > 0
    drift = np.abs(atlas.colour - before).mean(axis=2)[seen & INNER]
    assert np.median(drift) < 3.0, np.median(drift)
    # in the frame's lighting the atlas is the darker frame's
    assert abs(atlas.image("frame")[seen & INNER].mean() / atlas.image()[seen & INNER].mean() - 0.7) < 0.03
    # without correction the darker frame would have pulled the atlas by ~30 %
    plain = TextureAtlas(S, gain_limits=(1.0, 1.0))
    take(plain, gl, 0)
    take(plain, gl, 10, gain=0.7)
    assert np.median(np.abs(plain.colour - before).mean(axis=2)[seen & INNER]) > 5 * np.median(drift) + 5


def test_the_atlas_starts_afresh_on_another_face(gl):
    atlas = TextureAtlas(S)
    assert atlas.ensure(0, UV)
    take(atlas, gl, 0)
    assert not atlas.ensure(0, UV)
    assert (atlas.weight > 0).any() and atlas.updates == 1
    assert atlas.ensure(1, UV)
    assert not (atlas.weight > 0).any() and atlas.updates == 0 and (atlas.gain == 1).all()
    assert atlas.ensure(1, UV[::-1].copy())   # another layout is another atlas too


def test_uv_layout_keeps_texcoords_or_projects_the_neutral_frontally():
    np.testing.assert_array_equal(uv_layout(MESH, UV), UV)
    uv = uv_layout(MESH)
    assert uv.min() >= 0 and uv.max() <= 1
    # frontal: x to the right, y up -> v down; uniform scale
    top, right = np.argmax(MESH[:, 1]), np.argmax(MESH[:, 0])
    assert uv[top, 1] < 0.05 and uv[right, 0] > 0.95


def test_frontality_is_measured_under_an_affine_camera_too():
    """An orthographic fit's camera is at infinity: the flat rim of the bump faces it squarely
    (the camera's direction is its centre's, not a vector of zeros)."""
    X = pose(MESH, 0)
    P = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])   # pixels = x, y
    flat = MESH[:, 2] < 0.5
    for camera in (P, estimate_projection(X, project_pixels(K, X))):
        cos = vertex_frontality(X, TRI, camera)
        assert np.median(cos[flat]) > 0.95, np.median(cos[flat])
        assert cos[np.argmax(MESH[:, 2])] > 0.95   # the bump's top


@pytest.mark.parametrize("thread", [False, True], ids=["inline", "own thread and context"])
def test_a_surface_hidden_in_the_current_view_gets_the_atlas_colours(thread):
    """The head seen turned 50 degrees, re-posed frontally by the 'edit': the side of the bump the
    camera does not see is shown. With the atlas (learned from earlier frames) it has its colours;
    without it, the stretched colours of the sliver the camera saw. The same with the atlas's
    updates on a thread of their own (waited for after each frame, so that none is skipped)."""
    yaws = (0, -35, 35, 50)
    outs = {}
    for on in (False, True):
        with Compositor(W, H, atlas=on, atlas_size=S, atlas_thread=thread) as comp:
            for yaw in yaws:
                frame, X, px = view(yaw)
                out = comp.render(frame, X, px, TRI, X, uv=UV)   # no edit: the atlas only learns
                assert np.array_equal(out, frame)
                if comp.memory is not None:
                    comp.memory.wait()
            if on:
                assert comp.atlas.updates == len(yaws)
                assert comp.memory.current is not thread   # with a thread: the GL work is its own too
            centre = pose(MESH, 50).mean(axis=0)
            frontal = pose(MESH, 0)
            deformed = frontal - frontal.mean(axis=0) + centre
            outs[on] = comp.render(frame, X, px, TRI, deformed, uv=UV)
            weight = comp.atlas_region
    truth_X = pose(MESH, 0) - pose(MESH, 0).mean(axis=0) + pose(MESH, 50).mean(axis=0)
    truth = np.clip(np.rint(render_textured(K, truth_X, TRI, UV * T, np.ones(len(MESH)), TEXTURE, BACKGROUND)),
                    0, 255).astype(np.uint8)
    # the bump's side that faced away at yaw 50 (the model's -x side of the bump) in the truth's pixels
    side = (MESH[:, 0] < -5) & (MESH[:, 0] > -25) & (np.abs(MESH[:, 1]) < 15)
    pts = reference_project(K, truth_X[side])[0]
    region = np.zeros((H, W), np.uint8)
    cv2.fillConvexPoly(region, cv2.convexHull(np.round(pts).astype(np.int32)), 1)
    region = region.astype(bool)
    err = {on: float(np.abs(outs[on].astype(np.float32) - truth)[region].mean()) for on in outs}
    assert err[True] < 0.6 * err[False], err
    assert weight is not None and weight[region[comp.box[1]:comp.box[3], comp.box[0]:comp.box[2]]].mean() > 0.5


@pytest.mark.slow
def test_process_save_texture_writes_the_atlas_in_the_uv_layout(data_dir, models_dir, tmp_path):
    for model in ("facemesh", "sfm"):
        path = tmp_path / f"texture_{model}.png"
        done = subprocess.run([sys.executable, "-m", "facesculpt.cli", "process", str(data_dir / "video" / "d3.mp4"),
                               "-o", str(tmp_path / f"out_{model}.mp4"), "--model", model, "--max-frames", "8",
                               "--save-texture", str(path), "--quiet"], cwd=REPO, capture_output=True, text=True,
                              timeout=300)
        assert done.returncode == 0, done.stderr
        img = cv2.imread(str(path))
        assert img is not None and img.shape == (256, 256, 3)
        seen = img.max(axis=2) > 0
        assert 0.2 < seen.mean() < 0.95, seen.mean()   # the face's part of the layout, not all of it
    bad = subprocess.run([sys.executable, "-m", "facesculpt.cli", "process", str(data_dir / "video" / "d3.mp4"),
                          "-o", str(tmp_path / "x.mp4"), "--save-texture", str(tmp_path / "t.jpg")], cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode != 0 and ".png" in bad.stderr


def test_face_texture_message_round_trips_and_checks_its_shapes():
    from facesculpt.msgs import DecodeError, FaceTexture, decode, encode

    msg = FaceTexture(stamp=5, model_id="sfm", face_id=1, image=np.zeros((32, 32, 3), np.uint8),
                      confidence=np.full((32, 32), 7, np.uint8), texcoords=UV, updates=3)
    _, back = decode([bytes(f) for f in encode(msg, "face/texture")])
    assert back.image.shape == (32, 32, 3) and back.confidence[0, 0] == 7 and back.updates == 3
    np.testing.assert_array_equal(back.texcoords, UV)
    bad = FaceTexture(image=np.zeros((32, 16, 3), np.uint8), confidence=np.zeros((32, 32), np.uint8),
                      texcoords=UV)
    with pytest.raises(DecodeError):
        decode([bytes(f) for f in encode(bad, "face/texture")])


@pytest.mark.slow
def test_the_renderer_node_publishes_the_latched_face_texture(graph, data_dir):
    from benchmarks.renderer_scene import place_marked, read_frames
    from facesculpt.msgs import FaceModel, FaceState, FaceTexture, Image
    from facesculpt.nodes.fitter import load_model
    from facesculpt.runtime.node import Node
    from facesculpt.runtime.qos import LATCHED

    class Feeder(Node):
        NAME = "atlas_feeder"

        def setup(self):
            self.image_pub = self.advertise("camera/image", Image)
            self.state_pub = self.advertise("face/state", FaceState)
            self.model_pub = self.advertise("face/model", FaceModel, qos=LATCHED)
            self.textures = []
            self.subscribe("face/texture", FaceTexture, self.textures.append, qos=LATCHED)

    model = load_model("sfm")
    pose = place_marked(model, "s18")
    frames = read_frames(data_dir, "s18", count=2)
    H, W = frames[0].shape[:2]
    graph.spawn("run", "renderer", "pairing=sync", "publish=false", "atlas=on", "atlas_every=1", "texture_size=64",
                "texture_period_s=0")
    feeder = graph.node(Feeder())
    for pub in (feeder.image_pub, feeder.state_pub):
        assert pub.wait_for_subscribers(1, 30.0)
    feeder.model_pub.publish(FaceModel(stamp=1, model_id=model.model_id, vertices=model.mean.astype(np.float32),
                                       triangles=model.triangles.astype(np.int32)))
    graph.spin_until(feeder, lambda: False, 1.0)
    for i, frame in enumerate(frames * 2):   # the atlas updates on a thread: a texture comes a frame or so later
        stamp = (i + 1) * 40_000_000
        feeder.image_pub.publish(Image(stamp=stamp, seq=i, image=frame, K=pose.K))
        feeder.state_pub.publish(FaceState(stamp=stamp, model_id=model.model_id, R=pose.R, t=np.zeros(3), scale=1.0,
                                           K=pose.K, vertices=pose.fitted.astype(np.float32),
                                           projected=pose.projected.astype(np.float32), image_size=[W, H],
                                           projection="perspective"))
        graph.spin_until(feeder, lambda: False, 0.3)
    assert graph.spin_until(feeder, lambda: len(feeder.textures) > 0, 20.0), "no face/texture"
    tex = feeder.textures[-1]
    assert tex.image.shape == (64, 64, 3) and tex.confidence.shape == (64, 64)
    assert tex.texcoords.shape == (len(model.mean.reshape(-1, 3)), 2) and 1 <= tex.updates <= 4
    seen = tex.image.max(axis=2) > 0
    assert 0.2 < seen.mean() < 0.98 and (tex.confidence[seen] > 0).mean() > 0.9
