"""Appearance-fitting benchmark (issue 20): how well the landmark fit registers the whole face, on
synthetic video with exact ground truth, by yaw bin; the baseline a photometric refinement must beat.

The realism benchmark's synthetic scene (``benchmarks/realism/``: the Surrey Face Model with a
random identity, textured from a real face, over a real background, turning smoothly: yaw ±25°,
pitch ±10°; true pose and shape known) is run through the project's own landmarks and SFM fitter
in perspective (``Pipeline.fit_frame``, as ``facesculpt process`` fits: 60° field of view, the
scene's). Per fitted frame, against the truth:

* pose error: the angle (degrees) of the rotation between the fitted and the true head rotation,
  and the error of the pitch alone;
* vertex reprojection error (px): mean image distance between each fitted vertex and the same
  vertex of the true head, over the vertices the truth shows, and over those at the face's outline
  (the visible vertices within ``OUTLINE_PX`` of the true head's silhouette: where the issue says
  registration errors show);
* jitter on real video (``--real-videos``): per shared video and model, the median frame-to-frame
  displacement of the fitted mesh's vertices (px) once its smooth motion is removed, over the
  frames where that motion is slow (:func:`realism.jitter.jitter`), for each method of
  :data:`METHODS`; next to it, the same metric on the face's own image motion (corners on the face
  tracked from frame to frame, :func:`realism.jitter.tracked_motion`): what a tracker that follows
  the pixels faithfully shows, true motion and the video's noise alike, since real video has no
  ground truth;
* jitter against the truth (``--still-frames``): the same metric on the synthetic head held
  nearly still (its true motion smooth, so every bit of jitter is the fit's), clean, with camera
  noise and with camera noise and H.264 (:data:`realism.jitter.CONDITIONS`);
* shape SNR (dB, seed 002): 10 log10 of the true shape's energy about its centroid over the squared
  error of a fitted shape after a similarity alignment: each frame's fitted model-space shape, and
  the fitter's learned identity (its neutral) at the end.

Writes ``results.md`` and ``results.json`` to ``--out`` (default: a new temporary folder) and
prints the table.

Run: ``python -m benchmarks.bench_appearance [--out DIR] [--frames 90] [--still-frames 120]``. Needs the shared data
(../shared/data or FACESCULPT_DATA) and ``facesculpt setup``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from benchmarks.realism.jitter import CONDITIONS, degraded, jitter, low_passed, still_steps, tracked_motion
from benchmarks.realism.metrics import changed
from benchmarks.realism.posed import render_all
from benchmarks.realism.raster import project_pixels
from benchmarks.realism.scene import FACING, FOV_DEG, head_pose, make_scene, rotation
from benchmarks.realism.scoring import YAW_BINS
from facesculpt.geometry.head_angles import euler_from_rotation
from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.paths import shared_data_dir

#: A visible vertex within this distance (px) of the true silhouette is an outline vertex.
OUTLINE_PX = 3.0
#: Frames of the still synthetic head left out of its jitter: the fit is learning the person.
STILL_SKIP_FRAMES = 20


def silhouette_distance(image: np.ndarray, background: np.ndarray) -> np.ndarray:
    """(H, W) float32: each pixel's distance (px) to the true head's outline (where the rendered
    head meets the background)."""
    head = changed(image, background).astype(np.uint8)
    head = cv2.morphologyEx(head, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    edge = cv2.morphologyEx(head, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8))
    return cv2.distanceTransform((edge == 0).astype(np.uint8), cv2.DIST_L2, 3)


def similarity_error(fitted: np.ndarray, true: np.ndarray) -> float:
    """Squared error (mm², summed) of ``fitted`` (V, 3) after the similarity that best maps it onto
    ``true`` (V, 3)."""
    A, B = fitted - fitted.mean(0), true - true.mean(0)
    U, S, Vt = np.linalg.svd(A.T @ B)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.diag([1.0, 1.0, d])
    R = U @ D @ Vt
    scale = (S * np.diag(D)).sum() / (A * A).sum()
    return float(((scale * A @ R - B) ** 2).sum())


def shape_snr(fitted: np.ndarray, true: np.ndarray) -> float:
    """Seed 002's SNR (dB) of a fitted shape (V, 3) against the true one (first V rows of ``true``)."""
    true = np.asarray(true, np.float64)[: len(fitted)]
    return float(10 * np.log10(((true - true.mean(0)) ** 2).sum() / similarity_error(np.asarray(fitted, np.float64), true)))


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra @ Rb.T) - 1.0) / 2.0, -1.0, 1.0))))


def score_frame(fit, truth: dict, i: int, image_size, background: np.ndarray, rest: np.ndarray, K: np.ndarray) -> dict:
    """One fitted frame's pose error (deg; and its pitch's alone), mean reprojection error over the visible vertices and over
    the outline ones (px), and the SNR (dB) of its fitted model-space shape against ``rest`` (V, 3); ``K`` the scene's
    intrinsics (the true vertices are projected in the fit's pixel convention, centres at integers)."""
    V = len(fit.projected)
    vis = truth["visible"][:V]
    true_px = project_pixels(K, truth["vertices"][:V])
    err = np.linalg.norm(np.asarray(fit.projected, np.float64) - true_px, axis=1)
    dist = silhouette_distance(truth["image"], background)
    px = np.clip(np.rint(true_px).astype(int), 0, [image_size[0] - 1, image_size[1] - 1])
    outline = vis & (dist[px[:, 1], px[:, 0]] <= OUTLINE_PX)
    yaw, pitch, _ = head_pose(i)
    R_true = rotation(yaw, pitch) @ FACING
    signed = euler_from_rotation(np.asarray(fit.R, np.float64))[1] - euler_from_rotation(R_true)[1]
    return {"yaw": yaw, "pitch": pitch, "pitch_error": signed,
            "pose_deg": rotation_angle(np.asarray(fit.R, np.float64), R_true), "pitch_deg": abs(signed),
            "all_px": float(err[vis].mean()), "outline_px": float(err[outline].mean()) if outline.any() else np.nan,
            "outline_vertices": int(outline.sum()), "frame_snr_db": shape_snr(np.asarray(fit.model_vertices), rest)}


def by_yaw(rows: list[dict]) -> dict:
    out = {}
    for lo, hi in YAW_BINS:
        sel = [r for r in rows if lo <= r["yaw"] < hi]
        if sel:
            out[f"{lo:+.0f}..{hi:+.0f}"] = {k: float(np.nanmean([r[k] for r in sel]))
                                            for k in ("pose_deg", "pitch_deg", "all_px", "outline_px", "frame_snr_db")} | {"frames": len(sel)}
    return out


def overall(rows: list[dict]) -> dict:
    """Over all scored frames: the mean pose error (deg), the pitch error's mean (deg, signed: fitted
    less true) and its correlation with the true pitch, and the mean outline error (px)."""
    pitch, error = np.array([r["pitch"] for r in rows]), np.array([r["pitch_error"] for r in rows])
    return {"pose_deg": float(np.mean([r["pose_deg"] for r in rows])), "pitch_error_deg": float(error.mean()),
            "r_pitch": float(np.corrcoef(error, pitch)[0, 1]), "all_px": float(np.mean([r["all_px"] for r in rows])),
            "outline_px": float(np.nanmean([r["outline_px"] for r in rows]))}


def _time_fits(faces, times: list) -> None:
    """Appends the CPU time (ms, the process's) of each of ``faces``' (the pipeline's
    :class:`FaceFitters`) fits, landmarks excluded, to ``times``."""
    fit = faces.fit

    def timed(*args, **kwargs):
        c0 = time.process_time()
        try:
            return fit(*args, **kwargs)
        finally:
            times.append((time.process_time() - c0) * 1e3)
    faces.fit = timed


def run(frames: list, truths: list, background: np.ndarray, scene, fitter_options: dict) -> tuple[dict, float, float]:
    """The landmark fit (SFM, perspective) over ``frames``: (figures by yaw bin and over all frames
    ("all"), shape SNR dB, {"ms": median wall ms a fit, "cpu_ms": median CPU ms a fit (the
    process's), "fit_cpu_ms": the same of ``Pipeline.fit_faces``' fit alone, landmarks excluded})."""
    from facesculpt.app.pipeline import Pipeline

    rows, took, cpu, fit_cpu = [], [], [], []
    size = (frames[0].shape[1], frames[0].shape[0])
    with Pipeline("sfm", fov_deg=FOV_DEG, fit=FitterConfig(**fitter_options)) as pipe:
        for i, frame in enumerate(frames):
            if i == 1:
                _time_fits(pipe.faces, fit_cpu)
            t0, c0 = time.perf_counter(), time.process_time()
            fit = pipe.fit_frame(frame, i / 25.0)
            took.append((time.perf_counter() - t0) * 1e3)
            cpu.append((time.process_time() - c0) * 1e3)
            if fit is not None:
                rows.append(score_frame(fit, truths[i], i, size, background, scene.rest, scene.K))
        neutral = np.asarray(pipe.neutral, np.float64)
    times = {"ms": float(np.median(took)), "cpu_ms": float(np.median(cpu)),
             "fit_cpu_ms": float(np.median(fit_cpu)) if fit_cpu else float("nan")}
    return by_yaw(rows) | {"all": overall(rows)}, shape_snr(neutral, scene.rest), times


def fitted_pixels(frames: list, model: str, options: dict, **pipeline) -> np.ndarray:
    """(F, V, 2) ``model``'s fitted pixels over ``frames`` (``Pipeline`` options ``options`` and
    ``pipeline``; 25 frames/s), up to the first frame without a fit."""
    from facesculpt.app.pipeline import Pipeline

    tracks = []
    with Pipeline(model, fit=FitterConfig(**options), **pipeline) as pipe:
        for i, frame in enumerate(frames):
            fit = pipe.fit_frame(frame, i / 25.0)
            if fit is None:
                break
            tracks.append(np.asarray(fit.projected, np.float64))
    return np.array(tracks)


#: The fits compared: the project's default, the same without the landmark network's rotation
#: as the pose's prior (``rotation_prior_px=0``), and refined by appearance.
#: FitterConfig fields of each method.
METHODS = {
    "landmarks only": {},
    "landmarks only, no network rotation": {"rotation_prior_px": 0.0},
    "refined by appearance": {"refine": "appearance"},
    "refined pose (rigid regions)": {"refine": "pose"},
}


def methods_for(model: str, names: tuple[str, ...] = ()) -> dict:
    """The :data:`METHODS` (those named in ``names``; all without) that apply to ``model``: the
    network's rotation is a sparse fit's prior, so facemesh has no row without it."""
    return {k: v for k, v in METHODS.items()
            if (model == "sfm" or "rotation_prior_px" not in v) and (not names or k in names)}


def still_head_jitter(data: Path, workers: int, out: Path, frames: int, names: tuple[str, ...] = ()) -> dict:
    """The synthetic head held nearly still (``make_scene(motion="still")``: its true motion
    smooth, so all jitter is the fit's), under each image condition of :data:`CONDITIONS`:
    condition -> model -> {method: :func:`jitter` (px) of the fitted pixels, "face's tracked
    motion": that of :func:`.tracked_motion` started from the landmark fit (the tracker's own noise,
    here)}, the first STILL_SKIP_FRAMES left out (the fit is still learning the person)."""
    scene = make_scene(data, frames=frames, motion="still")
    clean = [t["image"] for t in render_all(scene, [(0.0, 0.0)], workers)[(0.0, 0.0)]]
    figures = {}
    for condition, (noise, crf) in CONDITIONS.items():
        images = degraded(clean, noise, crf, out)
        for model in ("facemesh", "sfm"):
            tracks = {k: fitted_pixels(images, model, o, fov_deg=FOV_DEG) for k, o in methods_for(model, names).items()}
            row = {k: jitter(t[STILL_SKIP_FRAMES:])[0] for k, t in tracks.items()}
            base = tracks["landmarks only"][STILL_SKIP_FRAMES:]
            motion = tracked_motion(images[STILL_SKIP_FRAMES:STILL_SKIP_FRAMES + len(base)], base)
            row["face's tracked motion"] = jitter(motion, still=still_steps(base))[0]
            figures.setdefault(condition, {})[model] = row
    return figures


def real_video_jitter(data: Path, videos: list[str], count: int, models: tuple[str, ...] = ("facemesh", "sfm"),
                      names: tuple[str, ...] = ()) -> dict:
    """"video model" -> {method: :func:`jitter` px, "face's tracked motion": the jitter of
    :func:`.tracked_motion` started from the landmark fit, "low-passed": that of the same motion
    through the fitter's smoothing of a still head (:func:`.low_passed`), both on the landmark fit's
    still frames, "still_frames": their number} over the first ``count`` frames of each shared video."""
    from benchmarks.realism.sequences import read_video

    out = {}
    for video in videos:
        frames = read_video(data / "video" / f"{video}.mp4", count)
        for model in models:
            tracks = {k: fitted_pixels(frames, model, o) for k, o in methods_for(model, names).items()}
            figures = {k: jitter(t) for k, t in tracks.items()}
            base = tracks["landmarks only"]
            motion, still = tracked_motion(frames[:len(base)], base), still_steps(base)
            out[f"{video} {model}"] = {
                **{k: f[0] for k, f in figures.items()}, "face's tracked motion": jitter(motion, still=still)[0],
                "low-passed": jitter(low_passed(motion, FitterConfig().smooth_min_cutoff), still=still)[0],
                "still_frames": figures["landmarks only"][1]}
    return out


def cost_on_video(data: Path, video: str, size: tuple[int, int], names: tuple[str, ...], frames: int = 80,
                  rounds: int = 2, skip: int = 20) -> dict:
    """The SFM fit's CPU time on ``video`` resized to ``size`` (W, H), per method of :data:`METHODS`
    (``names``; all without): {method: {"fit_cpu_ms": median of ``Pipeline.fit_faces``' fit alone
    (landmarks excluded), "frame_cpu_ms": of the whole frame}}, over ``rounds`` rounds that run the
    methods in turn (so a change of the machine's load falls on all of them alike), each on the
    first ``frames`` frames, the first ``skip`` left out (the refinement is still learning)."""
    from benchmarks.realism.sequences import read_video
    from facesculpt.app.pipeline import Pipeline

    images = [cv2.resize(f, size, interpolation=cv2.INTER_AREA) for f in read_video(data / "video" / f"{video}.mp4", frames)]
    times = {k: ([], []) for k in methods_for("sfm", names)}
    for _ in range(rounds):
        for name, options in methods_for("sfm", names).items():
            fit_cpu, frame_cpu = [], []
            with Pipeline("sfm", fit=FitterConfig(**options)) as pipe:
                for i, image in enumerate(images):
                    if i == 1:
                        _time_fits(pipe.faces, fit_cpu)
                    c0 = time.process_time()
                    pipe.fit_frame(image, i / 25.0)
                    frame_cpu.append((time.process_time() - c0) * 1e3)
            times[name][0].extend(fit_cpu[skip - 1:])
            times[name][1].extend(frame_cpu[skip:])
    return {k: {"fit_cpu_ms": float(np.median(f)), "frame_cpu_ms": float(np.median(w))} for k, (f, w) in times.items()}


def real_table(real: dict) -> list[str]:
    lines = ["", "| video | model | " + " | ".join(f"jitter, {name} (px)" for name in METHODS)
             + " | the face's tracked motion (px) | the same, low-passed as the fit (px) | still frames |",
             "| --- | --- | " + "--- | " * (len(METHODS) + 2) + "--- |"]
    for key, row in real.items():
        cells = [f"{row[k]:.3f}" if k in row else "–" for k in (*METHODS, "face's tracked motion", "low-passed")]
        lines.append(f"| {' | '.join(key.split(' '))} | {' | '.join(cells)} | {row['still_frames']} |")
    return lines


def still_table(still: dict) -> list[str]:
    lines = ["", "Jitter against the truth: the synthetic head held nearly still (its true motion smooth)",
             "", "| image | model | " + " | ".join(f"jitter, {name} (px)" for name in METHODS)
             + " | the face's tracked motion (px) |", "| --- | --- | " + "--- | " * (len(METHODS) + 1)]
    for condition, models in still.items():
        for model, row in models.items():
            cells = [f"{row[k]:.4f}" if k in row else "–" for k in (*METHODS, "face's tracked motion")]
            lines.append(f"| {condition} | {model} | {' | '.join(cells)} |")
    return lines


def synthetic_table(results: dict) -> list[str]:
    """The synthetic set's tables: by yaw bin, over all frames, and the cost (CPU time as a ratio
    to the first method's, measured in the same run)."""
    lines = ["| method | yaw bin | frames | pose error (deg) | pitch error (deg) | all vertices (px) | outline vertices (px) "
             "| frame shape SNR (dB) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for name, r in results.items():
        for b, v in r["by_yaw"].items():
            lines.append(f"| {name} | {b} | {v['frames']} | {v['pose_deg']:.2f} | {v['pitch_deg']:.2f} | {v['all_px']:.2f} "
                         f"| {v['outline_px']:.2f} | {v['frame_snr_db']:.2f} |")
    first = next(iter(results.values()))
    lines += ["", "| method | pose error mean (deg) | pitch error mean (deg) | r(pitch error, pitch) | all vertices (px) "
              "| outline vertices (px) | identity SNR (dB, the learned neutral) | fit ms (median wall, landmarks "
              "included) | CPU ratio, frame (landmarks included) | CPU ratio, fit alone |",
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for name, r in results.items():
        a = r["all"]
        lines.append(f"| {name} | {a['pose_deg']:.2f} | {a['pitch_error_deg']:+.2f} | {a['r_pitch']:+.2f} "
                     f"| {a['all_px']:.2f} | {a['outline_px']:.2f} | {r['shape_snr_db']:.2f} | {r['fit_ms_median']:.1f} "
                     f"| {r['cpu_ms_median'] / first['cpu_ms_median']:.2f} "
                     f"| {r['fit_cpu_ms_median'] / first['fit_cpu_ms_median']:.2f} |")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=None, help="output folder (default: a new temporary folder)")
    p.add_argument("--frames", type=int, default=90, help="synthetic frames, 25 fps (default 90; 0: none)")
    p.add_argument("--workers", type=int, default=0, help="processes rendering the synthetic set (0: one per core)")
    p.add_argument("--real-videos", default="d0,d3,d12,s18", help="shared videos for the jitter figure ('' for none)")
    p.add_argument("--real-frames", type=int, default=150, help="frames of each real video (default 150)")
    p.add_argument("--still-frames", type=int, default=120,
                   help="frames of the still synthetic head for the jitter against the truth (default 120; 0: none)")
    p.add_argument("--methods", default="", help="comma-separated names of METHODS to run (default: all; the "
                                                 "first is the cost's reference)")
    p.add_argument("--cost-video", default="", help="a shared video (e.g. s18) on which each method's CPU time is "
                                                    "measured at 856x480 ('' for none)")
    p.add_argument("--jitter-models", default="facemesh,sfm", help="models whose real-video jitter is measured")
    args = p.parse_args(argv)
    data = shared_data_dir()
    if data is None:
        print("bench_appearance: the shared data folder is missing (../shared/data or FACESCULPT_DATA)", file=sys.stderr)
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_appearance_"))
    out.mkdir(parents=True, exist_ok=True)
    workers = args.workers or max(1, min(4, len(os.sched_getaffinity(0))))
    results, lines = {}, []
    names = tuple(m for m in args.methods.split(",") if m)
    if args.frames:
        scene = make_scene(data, frames=args.frames)
        truths = render_all(scene, [(0.0, 0.0)], workers)[(0.0, 0.0)]
        frames = [t["image"] for t in truths]
        for name, options in methods_for("sfm", names).items():
            bins, snr, times = run(frames, truths, scene.background, scene, options)
            overall_row = bins.pop("all")
            results[name] = {"by_yaw": bins, "all": overall_row, "shape_snr_db": snr, "fit_ms_median": times["ms"],
                             "cpu_ms_median": times["cpu_ms"], "fit_cpu_ms_median": times["fit_cpu_ms"]}
        lines = synthetic_table(results)
    if args.still_frames:
        still = still_head_jitter(data, workers, out, args.still_frames, names)
        results["still head jitter"] = still
        lines += still_table(still)
    videos = [v for v in args.real_videos.split(",") if v]
    if videos:
        real = real_video_jitter(data, videos, args.real_frames, tuple(m for m in args.jitter_models.split(",") if m),
                                 names)
        results["jitter"] = real
        lines += real_table(real)
    if args.cost_video:
        cost = cost_on_video(data, args.cost_video, (856, 480), names)
        results["cost"] = cost
        first = next(iter(cost.values()))
        lines += ["", f"CPU time on {args.cost_video} at 856x480, SFM (medians, methods alternated; ratio to the first)",
                  "", "| method | fit alone ms | ratio | frame ms (landmarks included) | ratio |", "| --- | --- | --- | --- | --- |"]
        lines += [f"| {k} | {v['fit_cpu_ms']:.1f} | {v['fit_cpu_ms'] / first['fit_cpu_ms']:.2f} | {v['frame_cpu_ms']:.1f} "
                  f"| {v['frame_cpu_ms'] / first['frame_cpu_ms']:.2f} |" for k, v in cost.items()]
    table = "\n".join(lines)
    (out / "results.md").write_text(table + "\n")
    (out / "results.json").write_text(json.dumps(results, indent=1))
    print(table)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
