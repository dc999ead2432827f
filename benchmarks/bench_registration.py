"""Registration of the landmark network's points on the model (issue 46): the diagnosis, and the
fitted head's rotation with and without a calibration.

    python -m benchmarks.bench_registration [--frames 90] [--out DIR] [--models sfm,facemesh]
        [--calibrate FILE] [--calibration FILE] [--oracles] [--photos] [--real-videos d0,d3,s18]
        [--jitter-videos d0,d3,s18]

The realism benchmark's synthetic scene (:mod:`realism.scene`: the Surrey Face Model with a random
identity, textured from a real face, turning yaw ±25°, pitch ±10°) is rendered with its true pose
and vertices, and the project's landmark network is run on every frame. Reported
(:mod:`realism.registration`):

* per inner iBUG point (18-68, the SFM's landmark vertices): the image offset of the network's
  point from the true head's vertex, regressed on sin(yaw) and sin(pitch) (px per unit sine, and
  the share of its variance the pose explains);
* the implied 3D offset of each point (the model-space point that explains its image positions
  at the true pose) and of all 468 network points from the true surface;
* how much of the error one global parameter explains (the face flattened along its depth: the
  image signature of a head turned less than the truth) against a fixed 3D offset per point;
* the network's own 3D points' rotation against the truth (slope of yaw and pitch), and the depth
  scale that makes it right;
* the fitted head's rotation error (``Pipeline.fit_frame``, default settings, as ``process`` fits)
  for each model: mean angle, mean after the constant offset between the model's head frame and
  the truth's is removed, the correlation of the pitch error with the pitch, and (SFM) the inner
  and outline vertices' image error.

``--calibrate FILE`` learns the SFM's landmark calibration (``facesculpt/nodes/fitter/calibration.py``) from
sequences of its own (as `facesculpt model calibrate` does: :mod:`facesculpt.app.landmark_calibration`)
and writes it; with it (or
``--calibration FILE``) the benchmark set is fitted with and without it, ``--photos`` adds the 43
hand-marked photos' NME, ``--real-videos`` the shared videos fitted frame by frame, ``--oracles``
the fits without each error source (the set's own offsets, no smoothing, the true points).

Writes ``registration.json`` and ``registration.md`` to ``--out`` and prints the tables. Needs the
shared data (../shared/data or FACESCULPT_DATA) and ``facesculpt setup``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

import facesculpt.nodes.fitter.calibration as nodes_calibration
from benchmarks.bench_appearance import OUTLINE_PX, rotation_angle, silhouette_distance
from benchmarks.realism import registration as reg
from benchmarks.realism.landmark_oracle import INNER
from benchmarks.realism.posed import render_all
from benchmarks.realism.raster import project_pixels
from benchmarks.realism.scene import FOV_DEG, make_scene
from facesculpt.app.landmark_calibration import track
from facesculpt.geometry.head_angles import euler_from_rotation
from facesculpt.geometry.ibug68 import IBUG68_FROM_MESH, IBUG68_GROUPS
from facesculpt.nodes.fitter.calibration import uncalibrated
from facesculpt.paths import shared_data_dir

GROUPS = ("right_eyebrow", "left_eyebrow", "nose_bridge", "nose_base", "right_eye", "left_eye",
          "outer_lips", "inner_lips")


def render(scene, workers: int) -> list:
    """:func:`realism.posed.render_all` of the scene at its own pose: per frame image, vertices."""
    return render_all(scene, [(0.0, 0.0)], workers)[(0.0, 0.0)]


def inner_rows(scene) -> tuple[list[int], np.ndarray]:
    """The inner iBUG points (0-based) with an SFM landmark vertex, and those vertices."""
    rows = [k for k in INNER if str(k + 1) in scene.landmarks]
    return rows, np.array([scene.landmarks[str(k + 1)] for k in rows])


def diagnose(scene, points: np.ndarray) -> dict:
    """The diagnosis figures of the network's points (F, 468, 3) on ``scene``."""
    from scipy.spatial import cKDTree

    from facesculpt.geometry.vertex_normals import vertex_normals

    K = scene.K
    R, c = reg.poses(scene)
    angles = np.array([scene.pose(i)[:2] for i in range(scene.frames)])
    yaw, pitch = angles[:, 0], angles[:, 1]
    rows, verts = inner_rows(scene)
    observed = points[:, IBUG68_FROM_MESH[rows], :2]
    X0 = scene.rest[verts]
    err = observed - reg.project_model(K, R, c, X0)
    fit = reg.pose_regression(err, yaw, pitch)
    X3 = reg.triangulate(K, R, c, observed)
    k_flat, rms_flat = reg.flattening(K, R, c, observed, X0)
    const = err - np.nanmean(err, axis=0, keepdims=True)
    out = {"frames": int(scene.frames), "rms_vertex_px": reg.rms(err), "rms_constant_removed_px": reg.rms(const),
           "rms_flattened_px": rms_flat, "flattening_scale": k_flat,
           "rms_3d_offset_px": reg.rms(observed - reg.project_model(K, R, c, X3)),
           "rms_pose_regression_px": reg.rms(err - fit["fitted"]),
           "r2_pose_mean": float(np.mean(fit["r2"])), "points": {}}
    offsets = X3 - X0
    for j, k in enumerate(rows):
        out["points"][str(k + 1)] = {"coef_px": fit["coef"][j].round(3).tolist(), "r2": fit["r2"][j].round(3).tolist(),
                                     "offset_mm": offsets[j].round(2).tolist()}
    out["groups"] = {}
    for g in GROUPS:
        sel = [j for j, k in enumerate(rows) if k in IBUG68_GROUPS[g]]
        if sel:
            out["groups"][g] = {"x_per_sin_yaw_px": float(np.mean(fit["coef"][sel, 0, 1])),
                                "y_per_sin_pitch_px": float(np.mean(fit["coef"][sel, 1, 2])),
                                "r2": float(np.mean(fit["r2"][sel])),
                                "offset_mm": np.mean(offsets[sel], axis=0).round(2).tolist(),
                                "offset_length_mm": float(np.mean(np.linalg.norm(offsets[sel], axis=1)))}
    # all 468 points: the model-space point each stands for, against the true surface
    all3 = reg.triangulate(K, R, c, points[:, :, :2])
    Vm = scene.model_vertices
    dist, near = cKDTree(scene.rest[:Vm]).query(all3)
    normals = vertex_normals(scene.rest[:Vm], scene.model_triangles)
    normal_mm = np.einsum("ij,ij->i", all3 - scene.rest[near], normals[near])
    out["mesh_points"] = {"median_from_vertex_mm": float(np.median(dist)), "p90_from_vertex_mm": float(np.percentile(dist, 90)),
                          "median_normal_offset_mm": float(np.median(normal_mm)),
                          "rms_px": reg.rms(points[:, :, :2] - reg.project_model(K, R, c, all3))}
    # the network's own 3D points: their rotation against the truth
    rigid = np.unique(IBUG68_FROM_MESH[27:48])
    for label, sel in (("all 468", None), ("rigid (nose, eyes)", rigid)):
        r1 = reg.network_rotation(points, R, 1.0, sel)
        scale, rb = reg.best_depth_scale(points, R, sel)
        out.setdefault("network_rotation", {})[label] = {
            "yaw_slope": r1["yaw_slope"], "pitch_slope": r1["pitch_slope"],
            "yaw_error_deg": float(np.nanmean(np.abs(r1["yaw"] - r1["true_yaw"]))),
            "pitch_error_deg": float(np.nanmean(np.abs(r1["pitch"] - r1["true_pitch"]))),
            "best_depth_scale": scale, "yaw_slope_at_best": rb["yaw_slope"], "pitch_slope_at_best": rb["pitch_slope"]}
    return out


def _offset_removed(R_fit: np.ndarray, R_true: np.ndarray) -> np.ndarray:
    """Per-frame angle (deg) between the fitted rotations and the true ones after the constant
    offset (chordal mean of R_trueᵀ R_fit) between the two head frames is taken out."""
    from facesculpt.nodes.fitter.pose import nearest_rotation

    D = nearest_rotation(sum(Rt.T @ Rf for Rf, Rt in zip(R_fit, R_true)))
    return np.array([rotation_angle(Rf, Rt @ D) for Rf, Rt in zip(R_fit, R_true)])


def fitted_rotation(scene, frames: list, truths: list, model, skip: int = 0, config: dict | None = None,
                    **pipeline) -> dict:
    """``Pipeline(model)`` over the frames (25 frames/s): rotation error (deg; mean, and mean with
    the constant head-frame offset removed), pitch error's correlation with the true pitch, and for
    the SFM the visible inner / outline vertices' image error (px). Frames before ``skip`` are
    fitted but not scored (the fit's median ms, landmarks excluded, over all); ``config``: :class:`FitterConfig` fields changed from the pipeline's."""
    import dataclasses

    from facesculpt.app.pipeline import Pipeline

    R_true, _ = reg.poses(scene)
    size = (frames[0].shape[1], frames[0].shape[0])
    got, inner, outline, took = [], [], [], []
    with Pipeline(model, fov_deg=FOV_DEG, **pipeline) as pipe:
        pipe.fitter_config = dataclasses.replace(pipe.fitter_config, **(config or {}))
        for i, frame in enumerate(frames):
            timings = {}
            fit = pipe.fit_frame(frame, i / 25.0, timings)
            took.append(timings.get("fit", np.nan))
            if fit is None or i < skip:
                continue
            got.append((i, np.asarray(fit.R, np.float64)))
            if not pipe.model.dense:
                truth = truths[i]
                V = len(fit.projected)
                vis = truth["visible"][:V]
                err = np.linalg.norm(np.asarray(fit.projected, np.float64) - project_pixels(scene.K, truth["vertices"][:V]), axis=1)
                dist = silhouette_distance(truth["image"], scene.background)
                px = np.clip(np.rint(project_pixels(scene.K, truth["vertices"][:V])).astype(int), 0, [size[0] - 1, size[1] - 1])
                edge = vis & (dist[px[:, 1], px[:, 0]] <= OUTLINE_PX)
                inner.append(float(err[vis & ~edge].mean()))
                outline.append(float(err[edge].mean()) if edge.any() else np.nan)
    idx = np.array([i for i, _ in got])
    Rf = np.array([R for _, R in got])
    Rt = R_true[idx]
    true_pitch = np.array([euler_from_rotation(R)[1] for R in Rt])
    pitch_err = np.array([euler_from_rotation(R)[1] for R in Rf]) - true_pitch
    yaw_err = np.array([euler_from_rotation(R)[0] for R in Rf]) - np.array([euler_from_rotation(R)[0] for R in Rt])
    out = {"frames": len(idx), "rotation_deg": float(np.mean([rotation_angle(a, b) for a, b in zip(Rf, Rt)])),
           "rotation_offset_removed_deg": float(np.mean(_offset_removed(Rf, Rt))),
           "pitch_error_mean_deg": float(pitch_err.mean()), "pitch_error_sd_deg": float(pitch_err.std()),
           "r_pitch_error_pitch": float(np.corrcoef(pitch_err, true_pitch)[0, 1]),
           "yaw_error_sd_deg": float(yaw_err.std()), "fit_ms_median": float(np.nanmedian(took)),
           "r_yaw_error_yaw": float(np.corrcoef(yaw_err, [euler_from_rotation(R)[0] for R in Rt])[0, 1])}
    if inner:
        out["inner_px"], out["outline_px"] = float(np.mean(inner)), float(np.nanmean(outline))
    return out


def diagnosis_lines(d: dict) -> list[str]:
    """The diagnosis as markdown lines."""
    lines = [f"Inner iBUG points ({len(d['points'])}), {d['frames']} frames: RMS image error from the true landmark vertex "
             f"{d['rms_vertex_px']:.2f} px; its constant part removed {d['rms_constant_removed_px']:.2f}; "
             f"the face's depth scaled by one factor ({d['flattening_scale']:.2f}) {d['rms_flattened_px']:.2f}; "
             f"a fixed 3D offset per point {d['rms_3d_offset_px']:.2f}; "
             f"per-point regression on sin(yaw), sin(pitch) {d['rms_pose_regression_px']:.2f} "
             f"(mean R² of the pose terms {d['r2_pose_mean']:.2f})", "",
             "| group | x px per sin(yaw) | y px per sin(pitch) | R² | implied 3D offset (x, y, z) mm | length mm |",
             "| --- | --- | --- | --- | --- | --- |"]
    for g, v in d["groups"].items():
        lines.append(f"| {g} | {v['x_per_sin_yaw_px']:+.2f} | {v['y_per_sin_pitch_px']:+.2f} | {v['r2']:.2f} "
                     f"| {v['offset_mm'][0]:+.1f}, {v['offset_mm'][1]:+.1f}, {v['offset_mm'][2]:+.1f} "
                     f"| {v['offset_length_mm']:.1f} |")
    m = d["mesh_points"]
    lines += ["", f"All 468 network points: the model point each stands for lies {m['median_from_vertex_mm']:.1f} mm "
              f"(median; 90 %: {m['p90_from_vertex_mm']:.1f}) from the nearest true vertex, "
              f"{m['median_normal_offset_mm']:+.1f} mm along its normal (median); RMS px at that point "
              f"{m['rms_px']:.2f}", "",
              "| network 3D points | yaw slope | pitch slope | yaw error deg | pitch error deg | best depth scale "
              "| yaw / pitch slope there |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for label, v in d["network_rotation"].items():
        lines.append(f"| {label} | {v['yaw_slope']:.2f} | {v['pitch_slope']:.2f} | {v['yaw_error_deg']:.2f} "
                     f"| {v['pitch_error_deg']:.2f} | {v['best_depth_scale']:.2f} "
                     f"| {v['yaw_slope_at_best']:.2f} / {v['pitch_slope_at_best']:.2f} |")
    return lines


def fit_lines(fits: dict) -> list[str]:
    """The fitted rotation table as markdown lines."""
    lines = ["| fit | frames | rotation error deg | offset removed deg | pitch error mean / sd deg | r(pitch error, pitch) "
             "| r(yaw error, yaw) | inner px | outline px | fit ms (median) / first row's |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    first = next(iter(fits.values()))["fit_ms_median"] if fits else np.nan
    for name, f in fits.items():
        lines.append(f"| {name} | {f['frames']} | {f['rotation_deg']:.2f} | {f['rotation_offset_removed_deg']:.2f} "
                     f"| {f['pitch_error_mean_deg']:+.2f} / {f['pitch_error_sd_deg']:.2f} | {f['r_pitch_error_pitch']:+.2f} "
                     f"| {f['r_yaw_error_yaw']:+.2f} | {f.get('inner_px', np.nan):.2f} | {f.get('outline_px', np.nan):.2f} "
                     f"| {f['fit_ms_median']:.2f} / {f['fit_ms_median'] / first:.2f} |")
    return lines


def sequence_of(scene, points: np.ndarray, names: list[str]) -> dict:
    """A :func:`calibration.learn_calibration` sequence: the scene's poses, the network's points
    (F, 468, 3) for the landmarks ``names`` and the true head's vertices of them."""
    R, c = reg.poses(scene)
    rows = [int(n) - 1 for n in names]
    return {"K": scene.K, "R": R, "c": c, "observed": points[:, IBUG68_FROM_MESH[rows], :2],
            "vertices": scene.rest[[scene.landmarks[n] for n in names]],
            "yaw": np.array([scene.pose(i)[0] for i in range(scene.frames)])}


def frames_of(sequence: dict, keep: np.ndarray) -> dict:
    """``sequence`` with only the frames ``keep`` (F,) bool."""
    return {**sequence, "R": sequence["R"][keep], "c": sequence["c"][keep], "observed": sequence["observed"][keep],
            "yaw": sequence["yaw"][keep]}


def residual_px(sequence: dict, offsets) -> float:
    """RMS px of the network's points from the true head's landmark vertices moved by ``offsets``."""
    s = sequence
    return reg.rms(s["observed"] - reg.project_model(s["K"], s["R"], s["c"], s["vertices"] + offsets))


def leave_one_yaw_bin_out(sequences: list[dict]) -> list[dict]:
    """For each yaw bin of :data:`realism.scoring.YAW_BINS`: the calibration learned from the
    calibration frames outside it, scored on the frames inside it (landmark RMS px at the true
    pose, with the vertices and with the learned points)."""
    from benchmarks.realism.scoring import YAW_BINS

    rows = []
    for lo, hi in YAW_BINS:
        inside = [frames_of(s, (s["yaw"] >= lo) & (s["yaw"] < hi)) for s in sequences]
        outside = [frames_of(s, ~((s["yaw"] >= lo) & (s["yaw"] < hi))) for s in sequences]
        learned = nodes_calibration.learn_calibration(outside)["offsets"]
        test = [s for s in inside if len(s["R"])]
        rows.append({"bin": f"{lo:+.0f}..{hi:+.0f}", "frames": int(sum(len(s["R"]) for s in test)),
                     "vertex_px": float(np.mean([residual_px(s, 0.0) for s in test])),
                     "calibrated_px": float(np.mean([residual_px(s, learned) for s in test]))})
    return rows


def calibrate(data: Path, frames: int, workers: int, path: Path) -> tuple[dict, list[dict]]:
    """Learn the SFM's calibration as `facesculpt model calibrate` does (the same sequences,
    :mod:`facesculpt.app.landmark_calibration`) and write it to ``path``. Returns the learned
    calibration and the calibration sequences."""
    from facesculpt.app import landmark_calibration as lc
    from facesculpt.nodes.fitter import load_model

    model = uncalibrated(load_model("sfm"))
    sequences = lc.sequences(model, lc.shared_textures(data), frames, workers)
    textures = ", ".join(f"{v} frame {i}" for v, i in lc.SHARED_TEXTURES)
    calibrated, learned = lc.learn(model, sequences, f"the shared data's {textures} (bench_registration.py --calibrate)")
    lc.save_builtin(calibrated, path)
    return learned, sequences


def calibration_lines(results: dict) -> list[str]:
    """The calibration's figures as markdown lines."""
    lines = []
    if "leave_one_yaw_bin_out" in results:
        lines += ["Leave one yaw bin out (calibration sequences; landmark RMS px at the true pose):", "",
                  "| yaw bin | frames | model vertices | calibrated points |", "| --- | --- | --- | --- |"]
        lines += [f"| {r['bin']} | {r['frames']} | {r['vertex_px']:.2f} | {r['calibrated_px']:.2f} |"
                  for r in results["leave_one_yaw_bin_out"]]
        pitch, yaw = results["network_rotation_slopes"]
        lines += ["", f"The network's rigid 3D points on the calibration sequences turn {pitch:.3f} of the head's pitch "
                  f"and {yaw:.3f} of its yaw (the calibration's rotation gain is their inverse)", ""]
    if "benchmark_residual" in results:
        b = results["benchmark_residual"]
        lines += [f"Benchmark set (untouched), landmark RMS px at the true pose: model vertices {b['vertex_px']:.2f}, "
                  f"calibrated points {b['calibrated_px']:.2f}", ""]
    return lines


def photo_nme(data: Path, models: dict) -> dict:
    """NME of each model's landmark fit of the 43 hand-marked photos, fitted and matched as
    ``bench_fit_image.py`` does: the mean distance of the fitted landmarks from people's marks over
    the outer-eye-corner distance, with the landmarks the fitted vertices they were matched to
    (``nme_vertices``, :func:`bench_fit_image.nme`) and those moved by the model's calibration
    (``nme_landmarks``, :func:`calibration.fitted_landmarks`): name -> figures."""
    import cv2

    from benchmarks.bench_fit_image import nme
    from facesculpt.app.appearance_training import photo_fits
    from facesculpt.geometry.ibug68 import dlib_annotations
    from facesculpt.nodes.landmarks import LandmarkDetector

    detector = LandmarkDetector(max_faces=50, min_face=0.05)
    out = {}
    for name, model in models.items():
        fits, errors = {}, []
        for split in ("training", "testing"):
            for file, box, truth in dlib_annotations(data / "faces" / f"{split}_with_face_landmarks.xml"):
                if file not in fits:
                    fits[file] = photo_fits(cv2.imread(str(data / "faces" / file)), model, detector)
                centre = box[:2] + box[2:] / 2
                near = [(np.linalg.norm(f.projected.mean(0) - centre), i) for i, f in enumerate(fits[file])]
                near = [c for c in near if c[0] < box[2] / 2]
                if near:
                    fit = fits[file][min(near)[1]]
                    points = nodes_calibration.fitted_landmarks(fit, model)
                    err = [np.linalg.norm(points[str(k + 1)] - truth[k]) for k in range(68) if str(k + 1) in points]
                    errors.append((nme(fit, truth), float(np.mean(err) / np.linalg.norm(truth[36] - truth[45]))))
        out[name] = {"faces": len(errors), "nme_vertices": float(np.mean([e[0] for e in errors])),
                     "nme_landmarks": float(np.mean([e[1] for e in errors]))}
    return out


def oracle_fits(scene, frames: list, truths: list, points: np.ndarray, sfm, calibrated_model) -> dict:
    """What is left without each error source (``--oracles``): the SFM fitted with the benchmark
    set's own per-point offsets (learned from it: a bound, not a calibration), without the pose
    smoothing, and to the true inner landmarks (:mod:`realism.landmark_oracle`, KEEP 0; the jaw
    line stays the network's). Installs the oracle in this process: call it last."""
    from benchmarks.realism import landmark_oracle

    names = nodes_calibration.fixed_landmarks(sfm)
    own = nodes_calibration.learn_calibration([sequence_of(scene, points, names)])
    own_model = nodes_calibration.calibrated(sfm, names, own["offsets"], np.ones(len(names)), "the benchmark set's own")
    rows = {"sfm, the set's own offsets (bound)": fitted_rotation(scene, frames, truths, own_model),
            "sfm, no pose smoothing": fitted_rotation(scene, frames, truths, sfm, config={"smoothing": False}),
            "sfm, the set's own offsets, no pose smoothing": fitted_rotation(scene, frames, truths, own_model,
                                                                             config={"smoothing": False})}
    if calibrated_model is not None:
        rows["sfm, calibrated, no pose smoothing"] = fitted_rotation(scene, frames, truths, calibrated_model,
                                                                     config={"smoothing": False})
    size = (frames[0].shape[1], frames[0].shape[0])
    landmark_oracle.install(landmark_oracle.true_landmarks(scene), size, 0.0)
    rows["sfm, true inner points"] = fitted_rotation(scene, frames, truths, sfm)
    rows["sfm, true inner points, no pose smoothing"] = fitted_rotation(scene, frames, truths, sfm,
                                                                        config={"smoothing": False})
    return rows


#: Yaw bins of a real video's frames: this many, equally filled, by today's fitted yaw.
REAL_YAW_BINS = 3


def real_video(data: Path, video: str, models: dict, count: int) -> dict:
    """Each model fitted frame by frame (no identity accumulation, no smoothing) over the first
    ``count`` frames of a shared video: per yaw bin (:data:`REAL_YAW_BINS` equally filled bins of
    today's fitted yaw, the same frames for every model) the landmark residual (RMS px) and the
    mean identity shape; reported: the residual per bin, its correlation with |yaw|, and the
    identity's spread between bins (RMS mm of the bin means about their mean, over all vertices)."""
    import dataclasses

    from benchmarks.realism.sequences import read_video
    from facesculpt.app.pipeline import Pipeline

    frames = read_video(data / "video" / f"{video}.mp4", count)
    out, yaw = {}, None
    for name, model in models.items():
        rows = []
        with Pipeline(model, fov_deg=FOV_DEG) as pipe:
            pipe.fitter_config = dataclasses.replace(pipe.fitter_config, accumulate_identity=False, smoothing=False)
            for i, frame in enumerate(frames):
                fit = pipe.fit_frame(frame, i / 25.0)
                if fit is not None:
                    rows.append((i, euler_from_rotation(np.asarray(fit.R))[0], fit.residual_px, np.asarray(fit.alpha)))
        if yaw is None:   # the bins are today's fit's, the same frames for every model
            yaw = {i: y for i, y, _, _ in rows}
        edges = np.quantile(list(yaw.values()), np.linspace(0, 1, REAL_YAW_BINS + 1))
        edges[-1] += 1e-9
        by_bin, shapes = {}, []
        for lo, hi in zip(edges[:-1], edges[1:]):
            sel = [r for r in rows if r[0] in yaw and lo <= yaw[r[0]] < hi]
            if len(sel) >= 3:
                by_bin[f"{lo:+.1f}..{hi:+.1f}"] = {"frames": len(sel), "residual_px": float(np.mean([r[2] for r in sel]))}
                shapes.append(np.asarray(pipe.model.instance(np.mean([r[3] for r in sel], axis=0)), np.float64))
        spread = float(np.sqrt(np.mean(np.sum((np.array(shapes) - np.mean(shapes, axis=0)) ** 2, axis=2)))) if shapes else np.nan
        ys = [abs(yaw.get(r[0], np.nan)) for r in rows]
        out[name] = {"by_yaw": by_bin, "identity_spread_mm": spread,
                     "r_residual_abs_yaw": float(np.corrcoef(ys, [r[2] for r in rows])[0, 1])}
    return out


def real_jitter(data: Path, videos: list[str], models: dict, count: int) -> dict:
    """Each model's fitted-mesh jitter (:func:`realism.jitter.jitter`, px, default settings as
    ``process`` fits: identity accumulation and smoothing on) over the first ``count`` frames of
    each shared video: video -> name -> {"jitter_px", "still_frames"}."""
    from benchmarks.bench_appearance import fitted_pixels
    from benchmarks.realism.jitter import jitter
    from benchmarks.realism.sequences import read_video

    out = {}
    for video in videos:
        frames = read_video(data / "video" / f"{video}.mp4", count)
        for name, model in models.items():
            px, still = jitter(fitted_pixels(frames, model, {}))
            out.setdefault(video, {})[name] = {"jitter_px": px, "still_frames": still}
    return out


def real_lines(real: dict) -> list[str]:
    """The real videos' figures as markdown lines."""
    lines = ["", "| video | fit | residual px by today's yaw bin, degrees (frames) | r(residual, |yaw|) | identity spread between bins mm |",
             "| --- | --- | --- | --- | --- |"]
    for video, fits in real.items():
        for name, f in fits.items():
            bins = ", ".join(f"{b}: {v['residual_px']:.2f} ({v['frames']})" for b, v in f["by_yaw"].items())
            lines.append(f"| {video} | {name} | {bins} | {f['r_residual_abs_yaw']:+.2f} | {f['identity_spread_mm']:.3f} |")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=90, help="synthetic frames, 25 fps (default 90)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: a new temporary folder)")
    p.add_argument("--models", default="sfm,facemesh", help="models whose fit is scored ('' for none)")
    p.add_argument("--workers", type=int, default=0, help="rendering processes (0: one per core, at most 4)")
    p.add_argument("--calibrate", type=Path, default=None,
                   help="learn the SFM's landmark calibration from sequences of its own and write it here "
                        "(the fitter reads it from facesculpt.nodes.fitter.calibration.calibration_file('sfm_shape_3448'))")
    p.add_argument("--calibration-frames", type=int, default=80, help="frames of each calibration sequence (default 80)")
    p.add_argument("--oracles", action="store_true",
                   help="also the SFM fit without each error source (the set's own offsets, no smoothing, true points)")
    p.add_argument("--real-videos", default="", help="shared videos (e.g. d0,d3,s18) fitted with and without the calibration")
    p.add_argument("--jitter-videos", default="", help="shared videos (e.g. d0,d3,s18) whose fitted-mesh jitter is "
                   "measured with and without the calibration (default settings)")
    p.add_argument("--real-frames", type=int, default=150, help="frames of each real video (default 150)")
    p.add_argument("--photos", action="store_true", help="also the NME of the 43 hand-marked photos' landmark fits")
    p.add_argument("--calibration", type=Path, default=None,
                   help="a calibration file to score against today's fit (default: the one --calibrate writes)")
    args = p.parse_args(argv)
    data = shared_data_dir()
    if data is None:
        print("bench_registration: the shared data folder is missing (../shared/data or FACESCULPT_DATA)", file=sys.stderr)
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_registration_"))
    out.mkdir(parents=True, exist_ok=True)
    workers = args.workers or max(1, min(4, len(os.sched_getaffinity(0))))
    import dataclasses

    from facesculpt.nodes.fitter import load_model

    results = {"fits": {}}
    calibration = args.calibration
    if args.calibrate is not None:
        learned, sequences = calibrate(data, args.calibration_frames, workers, args.calibrate)
        results["leave_one_yaw_bin_out"] = leave_one_yaw_bin_out(sequences)
        results["calibration_sigma_px"] = learned["sigma"].round(2).tolist()
        results["network_rotation_slopes"] = learned["rotation_slopes"].round(3).tolist()
        calibration = calibration or args.calibrate
    scene = make_scene(data, frames=args.frames)
    truths = render(scene, workers)
    frames = [t["image"] for t in truths]
    points = track(frames)
    results["diagnosis"] = diagnose(scene, points)
    sfm = uncalibrated(load_model("sfm"))
    if calibration is not None:
        model = nodes_calibration.load_calibration(calibration, sfm)
        results["provenance"] = model.calibration
        names = nodes_calibration.fixed_landmarks(sfm)
        index = {n: i for i, n in enumerate(model.landmark_names)}
        bench = sequence_of(scene, points, names)
        results["benchmark_residual"] = {
            "vertex_px": residual_px(bench, 0.0),
            "calibrated_px": residual_px(bench, model.landmark_offsets[[index[n] for n in names]])}
    for name in [m for m in args.models.split(",") if m]:
        results["fits"][name] = fitted_rotation(scene, frames, truths, sfm if name == "sfm" else name)
        if name == "sfm" and calibration is not None:
            results["fits"]["sfm, calibrated"] = fitted_rotation(scene, frames, truths, model)
            for label, change in (("weights 1", {"landmark_weights": np.zeros(0, np.float32)}),
                                  ("no rotation gain", {"network_rotation_gain": np.zeros(0, np.float32)})):
                results["fits"][f"sfm, calibrated, {label}"] = fitted_rotation(
                    scene, frames, truths, dataclasses.replace(model, **change))
    if args.real_videos and calibration is not None:
        results["real"] = {v: real_video(data, v, {"sfm": sfm, "sfm, calibrated": model}, args.real_frames)
                           for v in args.real_videos.split(",") if v}
    if args.oracles:
        results["fits"] |= oracle_fits(scene, frames, truths, points, sfm, model if calibration is not None else None)
    lines = diagnosis_lines(results["diagnosis"]) + [""] + calibration_lines(results) + fit_lines(results["fits"])
    if "real" in results:
        lines += real_lines(results["real"])
    if args.jitter_videos and calibration is not None:
        results["jitter"] = real_jitter(data, [v for v in args.jitter_videos.split(",") if v],
                                        {"sfm": sfm, "sfm, calibrated": model}, args.real_frames)
        lines += ["", "| video | fit | jitter px (default settings) | still frames | / today's |", "| --- | --- | --- | --- | --- |"]
        for video, fits in results["jitter"].items():
            lines += [f"| {video} | {k} | {v['jitter_px']:.4f} | {v['still_frames']} | "
                      f"{v['jitter_px'] / fits['sfm']['jitter_px']:.2f} |" for k, v in fits.items()]
    if args.photos:
        results["photo_nme"] = photo_nme(data, {"sfm": sfm} | ({"sfm, calibrated": model} if calibration else {}))
        lines += ["", "| landmark fit of the hand-marked photos | faces | NME, fitted vertices | NME, calibrated points |",
                  "| --- | --- | --- | --- |"]
        lines += [f"| {k} | {v['faces']} | {v['nme_vertices']:.4f} | {v['nme_landmarks']:.4f} |"
                  for k, v in results["photo_nme"].items()]
    (out / "registration.md").write_text("\n".join(lines) + "\n")
    (out / "registration.json").write_text(json.dumps(results, indent=1))
    print("\n".join(lines))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
