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
  frames where that motion is slow (:func:`jitter`), for each method of :data:`METHODS`;
* shape SNR (dB, seed 002): 10 log10 of the true shape's energy about its centroid over the squared
  error of a fitted shape after a similarity alignment: each frame's fitted model-space shape, and
  the fitter's learned identity (its neutral) at the end.

Writes ``results.md`` and ``results.json`` to ``--out`` (default: a new temporary folder) and
prints the table.

Run: ``python benchmarks/bench_appearance.py [--out DIR] [--frames 90]``. Needs the shared data
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

sys.path.insert(0, str(Path(__file__).resolve().parent))

from realism.metrics import changed  # noqa: E402
from realism.posed import render_all  # noqa: E402
from realism.raster import project_pixels  # noqa: E402
from realism.scene import FACING, FOV_DEG, head_pose, make_scene, rotation  # noqa: E402
from realism.scoring import YAW_BINS  # noqa: E402

from facesculpt.geometry.head_angles import euler_from_rotation  # noqa: E402
from facesculpt.paths import shared_data_dir  # noqa: E402

#: A visible vertex within this distance (px) of the true silhouette is an outline vertex.
OUTLINE_PX = 3.0
#: A frame is still when the fitted mesh's smooth motion moves its median vertex less than this (px).
STILL_PX = 1.0


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
    pitch_err = abs(euler_from_rotation(np.asarray(fit.R, np.float64))[1] - euler_from_rotation(R_true)[1])
    return {"yaw": yaw, "pose_deg": rotation_angle(np.asarray(fit.R, np.float64), R_true), "pitch_deg": pitch_err,
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


def run(frames: list, truths: list, background: np.ndarray, scene, fitter_options: dict) -> tuple[dict, float, float]:
    """The landmark fit (SFM, perspective) over ``frames``: (figures by yaw bin, shape SNR dB, ms a fit)."""
    from facesculpt.app.pipeline import Pipeline

    rows, took = [], []
    size = (frames[0].shape[1], frames[0].shape[0])
    with Pipeline("sfm", fov_deg=FOV_DEG, **fitter_options) as pipe:
        for i, frame in enumerate(frames):
            t0 = time.perf_counter()
            fit = pipe.fit_frame(frame, i / 25.0)
            took.append((time.perf_counter() - t0) * 1e3)
            if fit is not None:
                rows.append(score_frame(fit, truths[i], i, size, background, scene.rest, scene.K))
        neutral = np.asarray(pipe.neutral, np.float64)
    return by_yaw(rows), shape_snr(neutral, scene.rest), float(np.median(took))


def jitter(tracks: np.ndarray, still_px: float = STILL_PX) -> tuple[float, int]:
    """(median jitter px, frames it is taken over) of a fitted mesh's pixels ``tracks`` (F, V, 2) over
    consecutive frames: the smooth motion (a Gaussian over ±3 frames) removed, the median vertex
    displacement of what remains from one frame to the next, on still frames (the smooth motion's
    median vertex speed under ``still_px`` px a frame)."""
    smooth = cv2.GaussianBlur(tracks.reshape(len(tracks), -1), (1, 7), 0, sigmaY=1.5).reshape(tracks.shape)
    rest = tracks - smooth
    step = np.median(np.linalg.norm(np.diff(rest, axis=0), axis=2), axis=1)
    speed = np.median(np.linalg.norm(np.diff(smooth, axis=0), axis=2), axis=1)
    still = speed < still_px
    still[:3] = still[-3:] = False   # the filter's ends
    return (float(np.median(step[still])) if still.any() else float("nan")), int(still.sum())


def real_jitter(data: Path, name: str, count: int, model: str, options: dict) -> tuple[float, int]:
    """:func:`jitter` of ``model``'s fit over the first ``count`` frames of the shared video ``name``
    (frames without a fit end the run there)."""
    from realism.sequences import read_video

    from facesculpt.app.pipeline import Pipeline

    tracks = []
    with Pipeline(model, **options) as pipe:
        for i, frame in enumerate(read_video(data / "video" / f"{name}.mp4", count)):
            fit = pipe.fit_frame(frame, i / 25.0)
            if fit is None:
                break
            tracks.append(np.asarray(fit.projected, np.float64))
    return jitter(np.array(tracks))


#: The fits compared: the project's default, the same without the landmark network's rotation
#: as the pose's prior (``rotation_prior_px=0``), and refined by appearance.
METHODS = {
    "landmarks only": {},
    "landmarks only, no network rotation": {"rotation_prior_px": 0.0},
    "refined by appearance": {"refine": "appearance"},
}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=None, help="output folder (default: a new temporary folder)")
    p.add_argument("--frames", type=int, default=90, help="synthetic frames, 25 fps (default 90)")
    p.add_argument("--workers", type=int, default=0, help="processes rendering the synthetic set (0: one per core)")
    p.add_argument("--real-videos", default="d0,d3,d12,s18", help="shared videos for the jitter figure ('' for none)")
    p.add_argument("--real-frames", type=int, default=150, help="frames of each real video (default 150)")
    args = p.parse_args(argv)
    data = shared_data_dir()
    if data is None:
        print("bench_appearance: the shared data folder is missing (../shared/data or FACESCULPT_DATA)", file=sys.stderr)
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_appearance_"))
    out.mkdir(parents=True, exist_ok=True)
    scene = make_scene(data, frames=args.frames)
    truths = render_all(scene, [(0.0, 0.0)], args.workers or max(1, min(4, len(os.sched_getaffinity(0)))))[(0.0, 0.0)]
    frames = [t["image"] for t in truths]
    results = {}
    for name, options in METHODS.items():
        bins, snr, ms = run(frames, truths, scene.background, scene, options)
        results[name] = {"by_yaw": bins, "shape_snr_db": snr, "fit_ms_median": ms}
    lines = ["| method | yaw bin | frames | pose error (deg) | pitch error (deg) | all vertices (px) | outline vertices (px) "
             "| frame shape SNR (dB) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for name, r in results.items():
        for b, v in r["by_yaw"].items():
            lines.append(f"| {name} | {b} | {v['frames']} | {v['pose_deg']:.2f} | {v['pitch_deg']:.2f} | {v['all_px']:.2f} "
                         f"| {v['outline_px']:.2f} "
                         f"| {v['frame_snr_db']:.2f} |")
    lines += ["", "| method | identity SNR (dB, the learned neutral) | fit ms (median, landmarks included) |",
              "| --- | --- | --- |"]
    lines += [f"| {name} | {r['shape_snr_db']:.2f} | {r['fit_ms_median']:.1f} |" for name, r in results.items()]
    videos = [v for v in args.real_videos.split(",") if v]
    if videos:
        lines += ["", "| video | model | " + " | ".join(f"jitter, {name} (px)" for name in METHODS) + " | still frames |",
                  "| --- | --- | " + "--- | " * len(METHODS) + "--- |"]
    for video in videos:
        for model in ("facemesh", "sfm"):
            # the network's rotation is a sparse fit's prior: facemesh has no row without it
            methods = {k: v for k, v in METHODS.items() if model == "sfm" or "rotation_prior_px" not in v}
            figures = {k: real_jitter(data, video, args.real_frames, model, o) for k, o in methods.items()}
            results.setdefault("jitter", {})[f"{video} {model}"] = {
                **{k: f[0] for k, f in figures.items()}, "still_frames": figures["landmarks only"][1]}
            cells = [f"{figures[k][0]:.3f}" if k in figures else "–" for k in METHODS]
            lines.append(f"| {video} | {model} | {' | '.join(cells)} | {figures['landmarks only'][1]} |")
    table = "\n".join(lines)
    (out / "results.md").write_text(table + "\n")
    (out / "results.json").write_text(json.dumps(results, indent=1))
    print(table)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
