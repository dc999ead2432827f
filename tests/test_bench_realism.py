"""The ground-truth realism benchmark's own parts (benchmarks/bench_realism.py): its reference
rasteriser, ground-truth edits, presets and metrics on a few synthetic frames. The full benchmark
(which runs ``facesculpt process``) is not run here."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from benchmarks.realism.edits import EDITS, preset
from benchmarks.realism.metrics import (
    Pooled,
    changed,
    edit_region,
    liquify,
    psnr_from_mse,
    shift_along,
    squared_error,
    ssim_map,
)
from benchmarks.realism.raster import render_textured
from benchmarks.realism.scoring import score_frame, summarise


@pytest.fixture(scope="module")
def synth(data_dir, models_dir):
    """Three frames (yaw 0, +10, +19 degrees) of the scene, unedited and with the nose and jaw
    edits."""
    if not (data_dir / "sfm").is_dir() or not (data_dir / "video" / "s18.mp4").is_file():
        pytest.skip("the benchmark needs ../shared/data/sfm and video/s18.mp4")
    from benchmarks.realism.scene import make_scene
    from benchmarks.realism.sequences import render_sequences

    scene = make_scene(data_dir, frames=3)
    scene_frames = [0, 4, 9]
    scene.frames = len(scene_frames)
    # the three frames of interest, renumbered 0..2
    pose = scene.pose
    scene.pose = lambda i: pose(scene_frames[i])
    to_camera = scene.to_camera
    scene.to_camera = lambda V, i: to_camera(V, scene_frames[i])
    seq = render_sequences(scene, [EDITS["nose"], EDITS["jaw"]], workers=1)
    return scene, seq


@pytest.mark.slow
def test_the_edited_render_differs_from_the_unedited_one_only_near_the_edit(synth):
    scene, seq = synth
    for i in range(3):
        diff = changed(seq.truth["nose"][i], seq.inputs[i], level=0)
        assert diff.sum() > 200, "the nose edit must show"
        ys, xs = np.nonzero(diff)
        tip = seq.p0[i][scene.landmarks["nose_tip"]]
        depth = scene.to_camera(scene.rest, i)[scene.landmarks["nose_tip"], 2]
        reach_px = (EDITS["nose"].radius + 10.0) * scene.K[0, 0] / depth
        far = np.hypot(xs + 0.5 - tip[0], ys + 0.5 - tip[1]) > reach_px
        assert not far.any(), f"frame {i}: {far.sum()} changed pixels farther than {reach_px:.0f} px from the nose tip"
        # pixels more than a few px from the head are the background, exactly
        near = cv2.dilate(seq.face[i].astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
        assert near.sum() < 0.5 * near.size
        assert np.array_equal(seq.inputs[i][~near], scene.background[~near])


@pytest.mark.slow
def test_the_reference_rasteriser_antialiases_the_head_over_the_background(synth):
    scene, _ = synth
    X = scene.to_camera(scene.rest, 0)
    args = (scene.K, X, scene.triangles, scene.texcoords, scene.alpha, scene.texture)
    black = render_textured(*args, np.zeros_like(scene.background, np.float32))
    white = render_textured(*args, np.full_like(scene.background, 255.0, np.float32))
    alpha = 1.0 - (white - black).mean(axis=2) / 255.0
    assert alpha.min() >= -1e-4 and alpha.max() <= 1 + 1e-4
    assert (alpha > 0.999).sum() > 10000, "a solid face"
    assert (alpha < 1e-6).sum() > 200000, "untouched background"
    assert ((alpha > 0.05) & (alpha < 0.95)).sum() > 300, "soft, anti-aliased borders"


def test_metrics_of_the_truth_against_itself_and_of_doing_nothing(synth):
    _, seq = synth
    for edit in ("nose", "jaw"):
        gt, inp = seq.truth[edit][1], seq.inputs[1]
        region = edit_region(gt, inp)
        assert region.any()
        se, n = squared_error(gt, gt, region)
        assert psnr_from_mse(se / n) == float("inf")
        assert abs(ssim_map(gt, gt)[region].mean() - 1.0) < 1e-9
        se, n = squared_error(inp, gt, region)
        nothing = psnr_from_mse(se / n)
        assert 10 < nothing < 45
        pool = Pooled()
        score_frame(pool, gt, gt, inp)
        s = summarise(pool)
        assert s["psnr"] == float("inf") and abs(s["sharpness"] - 1) < 1e-9 and abs(s["seam"] - 1) < 1e-9
        pool = Pooled()
        score_frame(pool, inp, gt, inp)
        s = summarise(pool)
        assert abs(s["psnr"] - nothing) < 1e-9 and np.isnan(s["seam"]), "doing nothing changes no region: no seam"
        vis = seq.visible[edit][1]
        liq = liquify(inp, seq.p0[1][vis], seq.p1[edit][1][vis])
        se, n = squared_error(liq, gt, region)
        assert psnr_from_mse(se / n) > nothing, f"{edit}: the ideal 2D warp is closer to the truth than nothing"


def test_handle_landing_measures_the_truths_displacement(synth):
    scene, seq = synth
    h = scene.landmarks["nose_tip"]
    for i in range(3):
        p0, d = seq.p0[i][h], seq.p1["nose"][i][h] - seq.p0[i][h]
        n = float(np.linalg.norm(d))
        moved = shift_along(seq.inputs[i], seq.truth["nose"][i], p0, d, seq.face[i], reach=2 * n + 3)
        still = shift_along(seq.inputs[i], seq.inputs[i], p0, d, seq.face[i], reach=2 * n + 3)
        assert abs(still) < 0.2
        assert 0.6 * n < moved < 1.1 * n, (moved, n)  # the patch around the tip moves a little less than the tip


def test_the_presets_load_on_both_models(synth):
    from facesculpt.nodes.deformer.edits import EditStack
    from facesculpt.nodes.fitter import load_model

    scene, _ = synth
    rest = scene.rest[: scene.model_vertices]
    for name in ("sfm", "facemesh"):
        model = load_model(name)
        stack = EditStack(np.asarray(model.mean, np.float64), np.asarray(model.triangles), model.landmark_names,
                          model.landmark_vertices)
        for spec in EDITS.values():
            stack.apply_preset(preset(spec, rest, scene.landmarks, scene.model_triangles))
            handles = list(stack.edits[0].offsets)
            assert len(handles) == len(spec.handles), (name, spec.name)
            if name == "sfm":
                from benchmarks.realism.edits import handle_vertex

                assert handles == [handle_vertex(k, scene.landmarks) for k in spec.handles]


def test_the_compositor_on_the_true_head_is_closer_to_the_truth_than_doing_nothing(synth):
    """The oracle rows: the project's compositor drawing the true head, with the true edit or with the
    deformer's own solve of the preset, is closer to the truth than doing nothing; on the nose (no
    background uncovered) the true edit is near exact, far closer than the ideal 2D warp."""
    from benchmarks.realism.edits import displacement
    from benchmarks.realism.oracle import deformer_displacement, oracle_frames

    scene, seq = synth
    for edit in ("nose", "jaw"):
        spec = EDITS[edit]
        true_edit = oracle_frames(scene, seq.inputs, displacement(spec, scene.rest, scene.landmarks), [0, 1, 2])
        ours = oracle_frames(scene, seq.inputs, deformer_displacement(spec, scene), [0, 1, 2])
        for i in (1, 2):
            gt, inp = seq.truth[edit][i], seq.inputs[i]
            region = edit_region(gt, inp)
            vis = seq.visible[edit][i]
            score = {name: psnr_from_mse(np.divide(*squared_error(img, gt, region)))
                     for name, img in (("nothing", inp), ("liquify", liquify(inp, seq.p0[i][vis], seq.p1[edit][i][vis])),
                                       ("true edit", true_edit[i]), ("preset", ours[i]))}
            assert score["true edit"] > score["nothing"] + 1 and score["preset"] > score["nothing"], (edit, i, score)
            if edit == "nose":  # an interior edit: no background to fill, the true edit is near exact
                assert score["true edit"] > max(score["liquify"] + 3, score["preset"]), (edit, i, score)


@pytest.mark.slow
def test_the_arap_truth_is_what_a_preset_stands_for(synth):
    """--truth-edit arap: the benchmark's own ARAP solver (gripping handles) moves each handle by
    exactly its offset and lands where the project's deformer settles the same preset with the same
    grip (0.2, an option), which the raised-cosine falloff does not."""
    from benchmarks.realism.edits import displacement, handle_vertex
    from benchmarks.realism.oracle import deformer_displacement

    scene, _ = synth
    n = scene.model_vertices
    for edit in ("nose", "jaw"):
        spec = EDITS[edit]
        arap = displacement(spec, scene.rest, scene.landmarks, "arap", scene.model_triangles, n)
        falloff = displacement(spec, scene.rest, scene.landmarks)
        ours = deformer_displacement(spec, scene, grip=0.2)
        for name, offset in spec.handles.items():
            assert np.allclose(arap[handle_vertex(name, scene.landmarks)], offset)
        assert np.abs(arap[:n] - ours[:n]).max() < 0.5, edit
        assert np.abs(falloff[:n] - ours[:n]).max() > 1.0, edit
        assert np.array_equal(arap[n:], falloff[n:])   # the vertices closing the mouth keep the falloff


@pytest.mark.slow
def test_the_paper_truth_is_the_single_vertex_arap_solved_by_libigl(synth):
    """--truth-edit paper: libigl's ARAP with each handle a single vertex moves each handle by
    exactly its offset, nothing beyond the ROI, and lands where the project's deformer settles the
    same preset with grip 0 (another solver: cotangent clamping, the ROI along the edges), far
    from the gripped truth, whose skin around the handle moves with it."""
    from benchmarks.realism.edits import displacement, handle_vertex
    from benchmarks.realism.paper_arap import geodesic_distances
    from facesculpt.nodes.deformer import EditStack

    scene, _ = synth
    n = scene.model_vertices
    rest = scene.rest[:n]
    for edit in ("nose", "jaw"):
        spec = EDITS[edit]
        paper = displacement(spec, scene.rest, scene.landmarks, "paper", scene.model_triangles, n)
        gripped = displacement(spec, scene.rest, scene.landmarks, "arap", scene.model_triangles, n)
        stack = EditStack(rest.astype(np.float32), scene.model_triangles, list(scene.landmarks),
                          list(scene.landmarks.values()), grip=0.0)
        stack.apply_preset(preset(spec, rest, scene.landmarks, scene.model_triangles))
        ours = stack.settle()
        handles = [handle_vertex(name, scene.landmarks) for name in spec.handles]
        for h, offset in zip(handles, spec.handles.values()):
            assert np.allclose(paper[h], offset)
        far = geodesic_distances(rest, scene.model_triangles, handles) > spec.radius
        assert far.sum() > n // 2 and np.all(paper[:n][far] == 0)
        gap = np.linalg.norm(paper[:n] - ours, axis=1)
        assert gap.max() < 2.0 and gap.mean() < 0.1, (edit, gap.max(), gap.mean())
        assert np.linalg.norm(paper[:n] - gripped[:n], axis=1).max() > 2.5, edit
        assert np.array_equal(paper[n:], gripped[n:])   # the vertices closing the mouth keep the falloff


def test_the_command_line_takes_several_truths_and_variants(capsys):
    from benchmarks import bench_realism
    a = bench_realism.parse_args(["--truth-edit", "paper,arap,paper", "--variants", "old=/tmp/a,grip0=/tmp/b"])
    assert a.truth_edit == ["paper", "arap"] and a.variants == [("old", "/tmp/a"), ("grip0", "/tmp/b")]
    for bad, said in ((["--truth-edit", "paper,cusp"], "unknown truth edit 'cusp'"),
                      (["--variants", "old"], "--variants takes LABEL=DIR pairs")):
        with pytest.raises(SystemExit):
            bench_realism.parse_args(bad)
        assert said in capsys.readouterr().err


def test_the_command_line_refuses_an_unknown_edit(capsys):
    from benchmarks import bench_realism
    with pytest.raises(SystemExit) as exc:
        bench_realism.parse_args(["--edits", "nose,ears"])
    assert exc.value.code == 2
    assert "unknown edit 'ears'" in capsys.readouterr().err


def test_the_landmark_oracle_moves_the_detectors_inner_points_toward_the_truth(synth, models_dir):
    """``--landmark-oracle KEEP``: the detector's inner iBUG points of a synthetic frame move to
    ``truth + KEEP * (detected - truth)``; the jaw line and the other mesh points stay the detector's."""
    from benchmarks.realism.landmark_oracle import move_toward_truth, true_landmarks
    from facesculpt.geometry import IBUG68_FROM_MESH, to_ibug68
    from facesculpt.nodes.landmarks import LandmarkDetector

    scene, seq = synth
    truth = true_landmarks(scene)
    assert truth.shape == (3, 68, 2)
    inner = np.isfinite(truth[0, :, 0])
    assert not inner[:17].any() and inner[17:].sum() >= 40   # the jaw line is a silhouette, no vertex
    # the detector's pixel convention (centres at integers), not the rasteriser's (centres at +0.5)
    for i in range(3):
        for k in np.flatnonzero(inner):
            np.testing.assert_allclose(truth[i, k], seq.p0[i][scene.landmarks[str(k + 1)]] - 0.5, atol=1e-9)
    faces = LandmarkDetector(models_dir).detect(seq.inputs[0])
    points = np.asarray(faces[0].points, np.float64)
    detected = to_ibug68(points).astype(np.float64)
    assert np.abs(detected[inner] - truth[0, inner]).max() > 1.0   # the detector is off somewhere
    for keep in (0.0, 0.5, 1.0):
        moved = move_toward_truth(points, truth[0], keep)
        got = to_ibug68(moved).astype(np.float64)
        np.testing.assert_allclose(got[inner], truth[0, inner] + keep * (detected[inner] - truth[0, inner]), atol=1e-3)
        np.testing.assert_array_equal(got[~inner], detected[~inner])
        untouched = np.setdiff1d(np.arange(len(points)), IBUG68_FROM_MESH[inner])
        np.testing.assert_array_equal(moved[untouched], points[untouched])


def test_the_landmark_oracle_is_for_the_surrey_model_only(capsys):
    from benchmarks import bench_realism
    with pytest.raises(SystemExit) as exc:
        bench_realism.parse_args(["--landmark-oracle", "0.5"])   # both models by default
    assert exc.value.code == 2
    assert "--models sfm" in capsys.readouterr().err
    assert bench_realism.parse_args(["--landmark-oracle", "0.5", "--models", "sfm"]).landmark_oracle == 0.5
