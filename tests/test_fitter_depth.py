"""The fitter with depth (issue 49): on synthetic Surrey-Face-Model faces whose depth image is
rendered by the realism benchmark's rasteriser, with noise, holes, a wall behind and a hand in
front of a cheek, the fit with depth is near the true pose and shape where the landmarks alone
are degrees and centimetres off; without a depth image nothing changes; a depth camera beside the
colour one is handled through its own K and transform."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import published_into

from benchmarks.realism.raster import rasterise
from benchmarks.synthetic_faces import make_face
from facesculpt.nodes.fitter import FitterConfig, load_model, make_fitter
from facesculpt.nodes.fitter.depth_fitting import DepthImage
from facesculpt.nodes.fitter.stage import fit_landmarks

SIZE = (640, 480)
K = np.array([[554.0, 0, 319.5], [0, 554.0, 239.5], [0, 0, 1]])


@pytest.fixture(scope="module")
def sfm(data_dir):
    return load_model("sfm")


def _depth_image(X: np.ndarray, triangles: np.ndarray, K_depth: np.ndarray, size, rng, wall_mm=1200.0) -> np.ndarray:
    """(H, W) uint16 mm of the camera-space mesh X (V, 3) in front of a wall, 1.2 mm noise,
    5 % random holes (pixel centres at integer coordinates, as K says)."""
    W, H = size
    uv = X[:, :2] / X[:, 2:3] * [K_depth[0, 0], K_depth[1, 1]] + K_depth[:2, 2] + 0.5
    frags = rasterise(uv, X[:, 2], triangles, (0, 0, W, H))
    z = np.where(frags.covered, frags.depth, wall_mm) + rng.normal(0, 1.2, (H, W))
    z[rng.random((H, W)) < 0.05] = 0
    return np.clip(np.rint(z), 0, 65535).astype(np.uint16)


def _rotation_error(R, R_true) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(np.asarray(R) @ np.asarray(R_true).T) - 1) / 2, -1, 1))))


def _frames(sfm, seed: int, n: int):
    """n frames of one person turning (yaw -20 to +25 degrees, 0.15 s apart: 50 degrees/s): (face,
    camera-space truth, depth)."""
    rng = np.random.default_rng(seed)
    alpha = np.zeros(sfm.num_shape, np.float32)
    alpha[:20] = rng.normal(0, 0.8, 20)
    out = []
    for i in range(n):
        f = make_face(sfm, rng, yaw=-20 + 45 * i / max(1, n - 1), pitch=5.0, roll=2.0, K=K, distance_mm=550.0,
                      alpha=alpha, beta_max=0.0, noise_px=2.0)
        X = f.vertices.astype(np.float64) @ f.R.T + f.t
        depth = _depth_image(X, np.asarray(sfm.triangles), K, SIZE, rng)
        # a hand in front of the left cheek, 120 mm nearer than the face
        u, v = (X[:, :2] / X[:, 2:3] * 554.0 + [319.5, 239.5]).T
        x0, y0 = int(np.percentile(u, 70)), int(np.percentile(v, 40))
        depth[y0:y0 + 60, x0:x0 + 50] = int(X[:, 2].min()) - 120
        out.append((f, X, depth))
    return out


@pytest.mark.slow
def test_depth_brings_pose_and_shape_near_the_truth(sfm):
    frames = _frames(sfm, 3, 6)
    fitters = {name: make_fitter(sfm, FitterConfig(), SIZE, K) for name in ("colour", "depth")}
    err = {name: [] for name in fitters}
    for i, (f, X, depth) in enumerate(frames):
        for name, fitter in fitters.items():
            fit = fitter.fit(f.noisy, f.ids, stamp=0.15 * i, depth=DepthImage(depth, K) if name == "depth" else None)
            rms = float(np.sqrt(((np.asarray(fit.vertices, np.float64) - X) ** 2).sum(axis=1).mean()))
            err[name].append((_rotation_error(fit.R, f.R), rms))
    colour, depth = np.mean(err["colour"], axis=0), np.mean(err["depth"], axis=0)
    assert depth[0] < 1.0 and depth[0] < colour[0], (colour, depth)   # degrees
    assert depth[1] < 2.5 and depth[1] < colour[1] / 3, (colour, depth)   # mm


def test_without_depth_nothing_changes(sfm):
    frames = _frames(sfm, 4, 3)
    plain, hooked = (make_fitter(sfm, FitterConfig(), SIZE, K) for _ in range(2))
    for i, (f, _, _) in enumerate(frames):
        a = plain.fit(f.noisy, f.ids, stamp=0.15 * i)
        b = fit_landmarks(hooked, f.noisy[None], np.ones(1), 0.15 * i, depth=None).fit
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.R, b.R)
    assert hooked.depth_refiner is None


def test_a_depth_image_that_misses_the_face_leaves_the_fit_as_it_is(sfm):
    (f, _, _), = _frames(sfm, 5, 1)
    plain, given = (make_fitter(sfm, FitterConfig(), SIZE, K) for _ in range(2))
    empty = np.zeros((480, 640), np.uint16)   # all holes
    wall = np.full((480, 640), 3000, np.uint16)   # only a wall, far behind the face
    for depth in (empty, wall):
        plain.reset()
        given.reset()
        a = plain.fit(f.noisy, f.ids)
        b = given.fit(f.noisy, f.ids, depth=DepthImage(depth, K))
        assert np.array_equal(a.vertices, b.vertices)


def test_a_depth_camera_beside_the_colour_camera(sfm):
    """The depth camera 25 mm to the side, turned 3 degrees, at 320x240 with its own K: the fit
    through its transform is as near the truth as with an aligned depth image."""
    frames = _frames(sfm, 6, 3)
    a = np.radians(3.0)
    T = np.eye(4)   # depth camera -> colour camera
    T[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    T[:3, 3] = [25.0, 0.0, 0.0]
    K_depth = np.array([[277.0, 0, 159.5], [0, 277.0, 119.5], [0, 0, 1]])
    rng = np.random.default_rng(0)
    fitter = make_fitter(sfm, FitterConfig(), SIZE, K)
    errors = []
    for i, (f, X, _) in enumerate(frames):
        Xd = (X - T[:3, 3]) @ T[:3, :3]   # the face in the depth camera's frame
        depth = _depth_image(Xd, np.asarray(sfm.triangles), K_depth, (320, 240), rng)
        fit = fitter.fit(f.noisy, f.ids, stamp=0.15 * i, depth=DepthImage(depth, K_depth, T))
        errors.append(_rotation_error(fit.R, f.R))
    assert np.mean(errors) < 1.0, errors


def test_points_at_follow_the_depth_cameras_transform():
    T = np.eye(4)
    T[:3, 3] = [40.0, -10.0, 5.0]
    K_depth = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])
    depth = np.full((240, 320), 800, np.uint16)   # a wall 800 mm from the depth camera
    depth[:, :60] = 0
    C = np.array([[0.0, 0.0, 795.0], [60.0, 30.0, 790.0], [-300.0, 0.0, 795.0]])   # colour camera mm
    P, valid = DepthImage(depth, K_depth, T).points_at(C)
    assert valid.tolist() == [True, True, False]   # the last one lands in the hole
    assert np.allclose(P[:2, 2], 805.0)   # the wall, seen from the colour camera 5 mm behind


@pytest.mark.slow
def test_the_fitter_node_fits_on_the_depth_of_the_landmarks_frame(sfm, monkeypatch, tmp_path):
    """The node with depth=on keeps camera/image's depth by stamp and fits each landmarks message
    on its frame's depth; with depth=off (the default) the same messages give the colour-only fit."""
    from facesculpt.msgs import FaceLandmarks, Image
    from facesculpt.nodes.fitter.node import FitterNode

    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    frames = _frames(sfm, 7, 4)
    errors = {}
    for setting in ("off", "on"):
        node = FitterNode(params={"model": "sfm", "depth": setting, "rotation_prior_px": 0.0})
        node.setup()
        states = published_into(node.state_pub, [])
        try:
            for i, (f, _, depth) in enumerate(frames):
                stamp = 1_000_000_000 + i * 150_000_000
                node.on_image(Image(stamp=stamp, image=np.zeros((480, 640, 3), np.uint8), K=K, depth=depth, depth_K=K))
                node.on_landmarks(FaceLandmarks(
                    stamp=stamp, points=np.c_[f.noisy, np.zeros(68)].astype(np.float32)[None],
                    scores=np.ones(1, np.float32), rois=np.zeros((1, 5), np.float32), image_size=[640, 480], K=K))
        finally:
            node.close()
        assert len(states) == len(frames) and node.counters.get("depth_without_frame", 0) == 0
        errors[setting] = np.mean([np.sqrt(((st.vertices - X) ** 2).sum(axis=1).mean())
                                   for st, (_, X, _) in zip(states, frames)])
    assert errors["on"] < 3.0 < errors["off"], errors


def test_the_dense_face_mesh_model_takes_its_distance_from_the_depth(models_dir):
    """facemesh (no shape basis): only the pose is refined, and the head's distance, which the
    468 points alone leave uncertain, comes from the depth."""
    from facesculpt.geometry.head_angles import rotation_from_euler

    mesh = load_model("facemesh")
    rng = np.random.default_rng(8)
    fitters = {name: make_fitter(mesh, FitterConfig(), SIZE, K) for name in ("colour", "depth")}
    errors = {name: [] for name in fitters}
    for i in range(4):
        R = rotation_from_euler(-10.0 + 8 * i, 4.0, 0.0)
        X = np.asarray(mesh.mean, np.float64) * 1.12 @ R.T + [5.0, 10.0, 520.0]   # a larger head than the mean
        pts = np.c_[X[:, :2] / X[:, 2:3] * 554.0 + [319.5, 239.5] + rng.normal(0, 1.0, (len(X), 2)),
                    (X[:, 2] - X[:, 2].mean()) * 554.0 / X[:, 2].mean()]   # the network's relative depth, px
        depth = _depth_image(X, np.asarray(mesh.triangles), K, SIZE, rng)
        for name, fitter in fitters.items():
            fit = fitter.fit(pts, stamp=0.1 * i,
                             depth=DepthImage(depth, K) if name == "depth" else None)
            errors[name].append(abs(float(np.median(fit.vertices[:, 2]) - np.median(X[:, 2]))))
    assert np.mean(errors["depth"]) < 5.0 < np.mean(errors["colour"]), errors


def test_the_refinement_stops_once_its_steps_are_below_what_it_resolves(models_dir, monkeypatch):
    """The Gauss-Newton steps end early when they converge, where running them all lands in the
    same place (the pose within a tenth of a degree and half a millimetre)."""
    from facesculpt.geometry.head_angles import rotation_from_euler
    from facesculpt.geometry.projection import project
    from facesculpt.nodes.fitter import depth_fitting
    from facesculpt.nodes.fitter.depth_fitting import DepthRefiner, fit_depth

    mesh = load_model("facemesh")
    ref = DepthRefiner(mesh, 0)
    R, t = rotation_from_euler(12.0, -5.0, 0.0), np.array([5.0, 10.0, 520.0])
    X = ref.mean @ R.T + t
    depth = DepthImage(_depth_image(X, ref.triangles, K, SIZE, np.random.default_rng(2)), K)
    lm = np.arange(len(X))
    px = project(X, K) + np.random.default_rng(3).normal(0, 1.0, (len(X), 2))

    def fit():
        return fit_depth(ref.mean, ref.basis, ref.triangles, rotation_from_euler(14.0, -4.0, 0.0), t + [0, 0, 15.0],
                         np.zeros(0), 0, np.repeat(lm[:, None], 3, axis=1), np.tile([1.0, 0, 0], (len(lm), 1)), px,
                         K, depth, outward=ref.outward, normals=ref.normals)

    early = fit()
    monkeypatch.setattr(depth_fitting, "CONVERGED_RAD", 0.0)
    full = fit()
    assert early.points > 0 and early.steps < full.steps == depth_fitting.ITERATIONS
    assert _rotation_error(early.R, full.R) < 0.1 and np.linalg.norm(early.t - full.t) < 0.5
    assert _rotation_error(early.R, R) < 0.5 and np.linalg.norm(early.t - t) < 2.0
