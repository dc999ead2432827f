"""`facesculpt process` of an RGB-D recording (issue 49), and edits that see depth: a short
synthetic RGB-D recording (the realism benchmark's head rendered with a depth buffer through its
structured-light noise model) written in a temp folder as colour + 16-bit depth PNGs and as a bag,
run as the command a person types; the edited depth's rules on a mesh whose depth is known; the
deformer's pick point against the depth image."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from facesculpt.nodes.camera.rgbd_sources import write_rgbd_folder
from facesculpt.nodes.renderer.edited_depth import edited_depth, mesh_depth

REPO = Path(__file__).resolve().parent.parent
FRAMES = 6
WALL_MM = 1000  # farther than this: the benchmark's wall, not the head


def process(*args, timeout: float = 180) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "facesculpt.cli", "process", *map(str, args)], cwd=REPO,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def recording(data_dir, models_dir, tmp_path_factory):
    """(folder of colour + depth PNGs with camera.json, bag of the same frames, K, [(colour, depth)])."""
    from benchmarks.realism.depth import rgbd_frame
    from benchmarks.realism.scene import make_scene
    from facesculpt.msgs import Image
    from facesculpt.runtime.bag import BagWriter

    scene = make_scene(data_dir, FRAMES, seed=5)
    frames = [rgbd_frame(scene, i, np.random.default_rng((5, i)))[:2] for i in range(FRAMES)]
    K = scene.K.copy()
    K[:2, 2] -= 0.5  # the scene's pixel centres are at +0.5, the project's at integers
    root = tmp_path_factory.mktemp("rgbd")
    folder = write_rgbd_folder(root / "rec", frames, K=K, fps=30)
    bag = root / "rec.mcap"
    with BagWriter(bag, compression="png") as w:
        for i, (colour, depth) in enumerate(frames):
            msg = Image(stamp=i * 33_333_333, seq=i, image=colour, K=K, frame_size=[640, 480], depth=depth, depth_K=K)
            w.write(msg.stamp, "camera/image", msg.to_frames())
    return folder, bag, K, frames


def _changes(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    return after.astype(np.float64) - before.astype(np.float64)


@pytest.mark.slow  # a process run, or the recording's rendering (about 3 s each here)
def test_a_folder_gives_the_edited_video_and_depth(recording, tmp_path):
    folder, _, _, frames = recording
    pattern = tmp_path / "depth" / "%05d.png"
    r = process(folder, "-o", tmp_path / "out.mp4", "--edits", "nose_longer", "--neutral-frames", "3",
                "--depth-out", pattern, "--quiet")
    assert r.returncode == 0, r.stderr
    assert f"wrote {FRAMES} frames" in r.stderr and f"{FRAMES} with a face" in r.stderr
    assert cv2.VideoCapture(str(tmp_path / "out.mp4")).get(cv2.CAP_PROP_FRAME_COUNT) == FRAMES
    edited_frames = 0
    for i, (_, depth) in enumerate(frames):
        out = cv2.imread(str(pattern).replace("%05d", f"{i:05d}"), cv2.IMREAD_UNCHANGED)
        assert out.dtype == np.uint16 and out.shape == depth.shape
        d = _changes(depth, out)
        head = cv2.dilate(((depth > 0) & (depth < WALL_MM)).astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
        assert not d[~head].any()  # the wall and everything off the head: the input's, bit for bit
        if (d != 0).sum() > 50:
            edited_frames += 1
            assert d[d != 0].mean() < 0, i  # a longer nose comes nearer the camera
    assert edited_frames >= FRAMES - 1


@pytest.mark.slow  # a process run, or the recording's rendering (about 3 s each here)
def test_a_bag_gives_an_rgbd_bag_of_the_edited_frames(recording, tmp_path):
    from facesculpt.nodes.camera.bag_source import BagImageSource
    from facesculpt.nodes.camera.rgbd_sources import RGBDFrame

    _, bag, K, frames = recording
    edited = tmp_path / "edited.mcap"
    r = process(f"bag:{bag}", "-o", tmp_path / "%03d.png", "--edits", "nose_longer", "--neutral-frames", "3",
                "--max-frames", 3, "--depth-out", edited, "--quiet")
    assert r.returncode == 0, r.stderr
    got = [f for f, _ in BagImageSource(str(edited), restamp=False).frames()]
    assert len(got) == 3 and all(isinstance(f, RGBDFrame) for f in got)
    for i, f in enumerate(got):
        assert np.array_equal(f.color, cv2.imread(str(tmp_path / f"{i:03d}.png")))  # the edited colour frame
        assert np.array_equal(f.depth_K, K) and np.array_equal(f.K, K)
    assert any((_changes(frames[i][1], f.depth) != 0).sum() > 50 for i, f in enumerate(got))
    assert not list(tmp_path.glob(".*writing*"))  # the staged file was renamed into place


@pytest.mark.slow  # a process run, or the recording's rendering (about 3 s each here)
def test_bad_depth_requests_are_one_sentence_and_touch_nothing(recording, tmp_path, data_dir):
    folder, bag, _, _ = recording
    r = process(data_dir / "video" / "d12.mp4", "-o", tmp_path / "o.mp4", "--depth-out", tmp_path / "d.mcap")
    assert r.returncode != 0 and "--depth-out needs an RGB-D input" in r.stderr
    existing = tmp_path / "00000.png"
    existing.write_bytes(b"a user's file")
    r = process(folder, "-o", tmp_path / "o.mp4", "--depth-out", tmp_path / "%05d.png")
    assert r.returncode != 0 and "never written over existing files" in r.stderr
    assert existing.read_bytes() == b"a user's file"
    r = process(f"bag:{bag}", "-o", tmp_path / "o.mp4", "--depth-out", bag)
    assert r.returncode != 0 and "over the input" in r.stderr
    assert not (tmp_path / "o.mp4").exists()


# -- the edited depth's rules, on a mesh whose depth is known ---------------------------------------
def _grid(z_mm: float, n: int = 41, half_mm: float = 100.0):
    """A square mesh (n x n vertices) facing the camera at ``z_mm``: (V, 3) mm, (T, 3)."""
    u = np.linspace(-half_mm, half_mm, n)
    x, y = np.meshgrid(u, u)
    V = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z_mm)])
    i = np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]
    T = np.concatenate([np.stack([i, i + 1, i + n], -1).reshape(-1, 3), np.stack([i + 1, i + n + 1, i + n], -1)
                        .reshape(-1, 3)])
    return V, T


def test_edited_depth_moves_the_face_keeps_the_rest():
    K = np.array([[500.0, 0, 159.5], [0, 500.0, 119.5], [0, 0, 1]])
    size = (320, 240)
    fitted, T = _grid(600.0)
    bump = 12.0 * np.exp(-(fitted[:, 0] ** 2 + fitted[:, 1] ** 2) / (2 * 25.0 ** 2))
    deformed = fitted - np.column_stack([np.zeros((len(fitted), 2)), bump])  # 12 mm toward the camera
    rng = np.random.default_rng(0)
    truth = np.where(np.isfinite(mesh_depth(fitted, T, K, size)), 600.0, 1500.0)
    depth = np.rint(truth + rng.normal(0, 1.0, truth.shape)).astype(np.uint16)
    depth[100:110, 150:160] = 0                 # a hole on the face
    depth[20:40, 60:100] = 450                  # a hand in front of the face
    out = edited_depth(depth, K, fitted, deformed, T)
    d = _changes(depth, out)
    assert out[119, 159] == depth[119, 159] - 12        # the bump's top: 12 mm nearer, the sensor's noise kept
    assert (out[100:110, 150:160] == 0).all()           # a hole stays a hole
    assert np.array_equal(out[20:40, 60:100], depth[20:40, 60:100])  # the hand stays in front
    assert not d[truth > 1000].any()                    # off the face: the input's
    # the same edit seen by a depth camera 25 mm to the side of the colour camera, with its own K
    T_dc = np.eye(4)
    T_dc[0, 3] = 25.0
    shifted = mesh_depth(deformed, T, K, size, T_dc)
    assert np.isfinite(shifted).sum() > 1000
    assert abs(shifted[np.isfinite(shifted)].min() - 588.0) < 0.5
    # a face that moves aside uncovers pixels nobody measured: they become holes, the new ones its depth
    moved = fitted + [20.0, 0.0, 0.0]
    out = edited_depth(depth, K, fitted, moved, T)
    left = np.isfinite(mesh_depth(fitted, T, K, size)) & ~np.isfinite(mesh_depth(moved, T, K, size))
    face = np.abs(depth.astype(np.float64) - 600) < 10
    assert (out[left & face] == 0).all() and (left & face).sum() > 100
    assert np.array_equal(out[left & (depth == 450)], depth[left & (depth == 450)])  # the hand, again
    new = ~np.isfinite(mesh_depth(fitted, T, K, size)) & np.isfinite(mesh_depth(moved, T, K, size))
    assert new.sum() > 100 and (out[new & (depth > 1000)] == 600).all()  # in front of the wall now


# -- edits see depth: the pick ray meets the surface the depth image measured ----------------------
@pytest.mark.slow  # a process run, or the recording's rendering (about 3 s each here)
def test_the_pick_point_lies_on_the_measured_depth(recording):
    from facesculpt.app.pipeline import Pipeline
    from facesculpt.nodes.deformer.picking import pick_vertex
    from facesculpt.nodes.fitter.depth_fitting import DepthImage

    _, _, K, frames = recording
    errors = {}
    for name in ("colour", "depth"):
        pipeline = Pipeline("sfm", K=K, expression=False)
        err = []
        for i, (colour, depth) in enumerate(frames[:4]):
            fit = pipeline.analyse(colour, i / 30, DepthImage(depth, K) if name == "depth" else None)[0][0]
        for x, y in np.asarray(fit.projected)[::25, :2]:  # pixels all over the face
            hit = pick_vertex(x, y, K, fit.vertices, pipeline.model.triangles)  # as the deformer picks
            z = depth[int(round(y)), int(round(x))]
            if hit is not None and 0 < z < WALL_MM:
                err.append(hit.point[2] - z)
        errors[name] = np.abs(err)
    assert len(errors["depth"]) > 50
    assert np.median(errors["depth"]) < 3.0 and np.percentile(errors["depth"], 90) < 8.0, errors["depth"]
    assert np.median(errors["colour"]) > 2 * np.median(errors["depth"])
