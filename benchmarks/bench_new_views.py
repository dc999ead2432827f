"""New-views benchmark (issue 18): ``facesculpt process --pose`` against the same head filmed at
the new pose, on synthetic videos with exact ground truth.

1. The synthetic scene of the realism benchmark (``benchmarks/realism/``: the Surrey Face Model
   with a random identity, textured from a real face, over a real background, turning smoothly:
   yaw ±25°, pitch ±10°), rendered at its own pose θ (the input) and at θ + Δ for each Δ of
   ``--deltas`` (yaw, then pitch): the head's own yaw (or pitch) increased by Δ, exactly what
   ``--pose yaw=Δ`` promises (:mod:`facesculpt.geometry.pose_offset`), turning about the scene's
   pivot (90 mm behind the model's origin).
2. ``facesculpt process SYNTH.mkv -o FRAMES/%05d.png --pose yaw=Δ --model M`` (a subprocess, as a
   user runs it, on a lossless FFV1 input) for each model, scored on every frame after
   ``--skip`` against the θ + Δ truth, next to "do nothing" (the input) and a 2D baseline: the
   input warped by the homography that best maps the head's visible vertices from θ to θ + Δ
   (an oracle: it is given the true vertex positions), applied over the head and faded out
   around it (no hole, no ghost: the best a 2D warp of the face region can do). ``process``'s
   default takes the surface the input frame sees badly (hidden or foreshortened at θ, shown at
   θ + Δ) from the stored view of the head closest to the one rendered (``--keyframes auto``:
   image-based rendering from keyframes, seed 003); the models of ``--geometry-models`` run once
   more with ``--keyframes off`` (geometry and the current frame only), those of
   ``--atlas-models`` with ``--atlas on`` (the face's texture memory too), those of
   ``--limit-off-models`` with ``--pose-limit off`` (the whole turn on every frame, as before issue
   51; by default a frame draws only the share of the turn that what is known of the surface it
   reveals allows: :mod:`facesculpt.nodes.renderer.pose_limit`).
3. Real videos (``--real-videos``, default d3, d12; no ground truth): ``process --face-camera 1`` at
   the default ``--face-camera-limit`` and at 45°; the project's landmarks and fitter run on the
   input and on each output, and the mean absolute yaw and pitch still needed to look into the
   camera is compared (``face_camera_VIDEO.png``: input | default limit | 45°, three frames).
4. Figures: PSNR (dB) and SSIM over the head region (where the input or the truth shows the
   head, dilated by 4 px), per Δ and method. Crops ``crops_yaw_D_MODEL.png`` (rows: the most
   turned-left, a frontal and the most turned-right scored frames; columns: input | result |
   ground truth | 2D homography).

Writes ``results.md``, ``results.json`` and the crops to ``--out`` (default: a new temporary
folder) and prints the table.

Run: ``python -m benchmarks.bench_new_views [--out DIR] [--frames 60] [--models facemesh,sfm]
[--deltas 5,10,15,20] [--pitch-deltas 5,10,15,20] [--geometry-models facemesh,sfm]
[--atlas-models facemesh,sfm]``. Needs the shared data (../shared/data or
FACESCULPT_DATA) and ``facesculpt setup``.
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

from benchmarks.realism.metrics import Pooled, changed, psnr_from_mse, squared_error, ssim_map
from benchmarks.realism.posed import render_all
from benchmarks.realism.report import side_by_side
from benchmarks.realism.scene import head_pose, make_scene
from benchmarks.realism.sequences import run_process, write_lossless
from facesculpt.geometry.pose_offset import FACE_CAMERA_LIMIT_DEG
from facesculpt.paths import shared_data_dir

#: Dilation (px) of the head's region for the scores.
REGION_DILATE_PX = 4
#: Width of the 2D baseline's fade around the head, as a share of the head's size.
FADE_FRACTION = 0.3

def head_mask(img: np.ndarray, background: np.ndarray) -> np.ndarray:
    """(H, W) bool: where the head covers the background, holes filled."""
    m = changed(img, background).astype(np.uint8)
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    filled = np.zeros_like(m)
    cv2.drawContours(filled, contours, -1, 1, thickness=cv2.FILLED)
    return filled.astype(bool)


def homography_baseline(inp: dict, truth: dict, background: np.ndarray) -> np.ndarray:
    """The input warped by the homography of the visible vertices from the input to the truth,
    over the head (where the input or the warped input shows it), faded out around it."""
    both = inp["visible"] & truth["visible"]
    H, _ = cv2.findHomography(inp["px"][both].astype(np.float32), truth["px"][both].astype(np.float32), 0)
    h, w = inp["image"].shape[:2]
    head = head_mask(inp["image"], background)
    moved = cv2.warpPerspective(head.astype(np.uint8), H, (w, h), flags=cv2.INTER_NEAREST).astype(bool)
    region = (head | moved).astype(np.uint8)
    ys, xs = np.nonzero(region)
    size = np.sqrt(max(np.ptp(xs) * np.ptp(ys), 1.0))
    fade = cv2.distanceTransform(1 - region, cv2.DIST_L2, 3) / (FADE_FRACTION * size)
    weight = np.clip(1.0 - fade, 0.0, 1.0)
    weight = weight * weight * (3 - 2 * weight)
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pts = np.stack([gx, gy, np.ones_like(gx)], -1) @ np.linalg.inv(H).T
    sx, sy = pts[..., 0] / pts[..., 2], pts[..., 1] / pts[..., 2]
    map_x = (gx + weight * (sx - gx)).astype(np.float32)
    map_y = (gy + weight * (sy - gy)).astype(np.float32)
    return cv2.remap(inp["image"], map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)


def score(frames: list, inputs: list, truths: list, background: np.ndarray, scored: list[int]) -> dict:
    """PSNR (dB) and SSIM of ``frames`` against ``truths`` over the head region of each scored frame."""
    pool = Pooled()
    for i in scored:
        region = head_mask(inputs[i]["image"], background) | head_mask(truths[i]["image"], background)
        region = cv2.dilate(region.astype(np.uint8), np.ones((2 * REGION_DILATE_PX + 1,) * 2, np.uint8)).astype(bool)
        se, n = squared_error(frames[i], truths[i]["image"], region)
        pool.add("se", se, n)
        pool.add("ssim", float(ssim_map(frames[i], truths[i]["image"])[region].sum()), int(region.sum()))
    return {"psnr": psnr_from_mse(pool.mean("se")), "ssim": pool.mean("ssim"), "frames": len(scored)}


def face_camera_residuals(frames: list, fov_deg: float = 60.0) -> np.ndarray:
    """(N, 2) degrees: per frame with a face, the yaw and pitch still needed to look into the camera
    (:func:`face_camera_offset` all the way, unclamped), from the project's landmarks and
    ``facemesh`` fitter run over ``frames`` in order, as ``process`` fits them."""
    from facesculpt.app.pipeline import Pipeline
    from facesculpt.geometry.pose_offset import face_camera_offset, head_pivot

    out = []
    with Pipeline("facemesh", fov_deg=fov_deg) as pipe:
        for i, frame in enumerate(frames):
            fit = pipe.fit_frame(frame, i / 25.0)
            if fit is not None:
                turn = face_camera_offset(fit.R, fit.t, fit.scale, head_pivot(pipe.neutral), 1.0, 90.0,
                                          perspective=fit.projection == "perspective")
                out.append((turn.yaw, turn.pitch))
    return np.array(out)


def real_face_camera(data: Path, name: str, count: int, out: Path, limits: list[float]) -> dict:
    """``process --face-camera 1`` on the shared video ``name`` (``count`` frames) at each
    ``--face-camera-limit`` of ``limits``: the mean absolute yaw and pitch still needed to look
    into the camera, refitted on the input and on each output; a picture input | outputs."""
    from benchmarks.realism.sequences import read_video

    video = data / "video" / f"{name}.mp4"
    inputs = read_video(video, count)
    row = {"input": np.abs(face_camera_residuals(inputs)).mean(axis=0).round(2).tolist()}
    shown = [inputs]
    for limit in limits:
        got, _ = run_process(video, out / "frames" / f"face_camera_{name}_{limit:g}", None, "facemesh",
                             max_frames=count, data=data,
                             extra_args=("--face-camera", "1", "--face-camera-limit", f"{limit:g}"))
        row[f"limit {limit:g}"] = np.abs(face_camera_residuals(got)).mean(axis=0).round(2).tolist()
        shown.append(got)
    picks = np.linspace(count // 6, count - 1, 3).astype(int)
    grid = np.vstack([np.hstack([seq[i] for seq in shown]) for i in picks])
    cv2.imwrite(str(out / f"face_camera_{name}.png"), grid)
    return row


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=None, help="output folder (default: a new temporary folder)")
    p.add_argument("--frames", type=int, default=60, help="synthetic frames, 25 fps (default 60)")
    p.add_argument("--skip", type=int, default=5, help="frames not scored at the start (default 5)")
    p.add_argument("--models", default="facemesh,sfm", help="models to run process with (default facemesh,sfm)")
    p.add_argument("--deltas", default="5,10,15,20", help="yaw offsets, degrees (default 5,10,15,20)")
    p.add_argument("--pitch-deltas", default="5,10,15,20", help="pitch offsets, degrees (default 5,10,15,20; '' for none)")
    p.add_argument("--geometry-models", default="facemesh,sfm",
                   help="models also run with process --keyframes off (geometry only, no stored views; '' for none)")
    p.add_argument("--atlas-models", default="facemesh,sfm",
                   help="models also run with process --atlas on (the face's texture memory; '' for none)")
    p.add_argument("--limit-off-models", default="facemesh",
                   help="models also run with process --pose-limit off (the whole turn on every frame, as before "
                        "issue 51; '' for none)")
    p.add_argument("--real-videos", default="d3,d12", help="shared videos run with --face-camera 1 ('' for none)")
    p.add_argument("--real-frames", type=int, default=90, help="frames of each real video (default 90)")
    p.add_argument("--workers", type=int, default=0, help="processes rendering the synthetic set (0: one per core)")
    a = p.parse_args(argv)
    a.models = [m for m in a.models.split(",") if m]
    a.atlas_models = [m for m in a.atlas_models.split(",") if m]
    a.geometry_models = [m for m in a.geometry_models.split(",") if m]
    a.limit_off_models = [m for m in a.limit_off_models.split(",") if m]
    a.real_videos = [v for v in a.real_videos.split(",") if v]
    a.offsets = [(float(d), 0.0) for d in a.deltas.split(",") if d] + \
                [(0.0, float(d)) for d in a.pitch_deltas.split(",") if d]
    if a.frames <= a.skip:
        p.error(f"--frames {a.frames} leaves no frame after --skip {a.skip}")
    return a


def runs(args) -> list[tuple[str, str, tuple]]:
    """(model, variant label, process options) of every process run per offset."""
    out = [(m, "--keyframes off", ("--keyframes", "off")) for m in args.geometry_models]
    out += [(m, "", ()) for m in args.models]
    out += [(m, "--atlas on", ("--atlas", "on")) for m in args.atlas_models]
    out += [(m, "--pose-limit off", ("--pose-limit", "off")) for m in args.limit_off_models]
    return out


def _name(offset: tuple[float, float]) -> str:
    dy, dp = offset
    return f"yaw={dy:g}" if dy else f"pitch={dp:g}"


def crop_rows(inputs: list, scored: list[int]) -> list[int]:
    yaw = np.array([head_pose(i)[0] for i in scored])
    return [scored[int(np.argmin(yaw))], scored[int(np.argmin(np.abs(yaw)))], scored[int(np.argmax(yaw))]]


def head_box(frames: list, background: np.ndarray, size: tuple[int, int], pad: int = 16) -> tuple[int, int, int, int]:
    """One square box around the head in every frame of ``frames``, inside the image."""
    W, H = size
    ys, xs = np.nonzero(np.logical_or.reduce([head_mask(f, background) for f in frames]))
    side = int(min(max(np.ptp(xs), np.ptp(ys)) + 2 * pad, W, H))
    cx, cy = (xs.min() + xs.max()) / 2, (ys.min() + ys.max()) / 2
    x0, y0 = int(np.clip(cx - side / 2, 0, W - side)), int(np.clip(cy - side / 2, 0, H - side))
    return x0, y0, x0 + side, y0 + side


def main(argv=None) -> int:
    args = parse_args(argv)
    data = shared_data_dir()
    if data is None:
        print("bench_new_views: the shared data folder is missing (../shared/data or FACESCULPT_DATA)", file=sys.stderr)
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_new_views_"))
    out.mkdir(parents=True, exist_ok=True)
    workers = args.workers or max(1, min(4, len(os.sched_getaffinity(0))))
    t0 = time.perf_counter()
    scene = make_scene(data, frames=args.frames)
    rendered = render_all(scene, [(0.0, 0.0)] + args.offsets, workers)
    inputs = rendered[(0.0, 0.0)]
    print(f"rendered {len(rendered)} sequences of {args.frames} frames in {time.perf_counter() - t0:.0f} s", flush=True)
    video = write_lossless([f["image"] for f in inputs], out / "synthetic.mkv")
    scored = list(range(args.skip, args.frames))
    bg = scene.background
    size = (bg.shape[1], bg.shape[0])
    results: dict = {}
    for offset in args.offsets:
        name, truths = _name(offset), rendered[offset]
        row = {"do nothing": score([f["image"] for f in inputs], inputs, truths, bg, scored)}
        homog = [homography_baseline(inputs[i], truths[i], bg) for i in range(args.frames)]
        row["2D homography"] = score(homog, inputs, truths, bg, scored)
        rows = crop_rows(inputs, scored)
        box = head_box([inputs[i]["image"] for i in rows] + [truths[i]["image"] for i in rows], bg, size)
        for m, variant, extra in runs(args):
            label = f"process {m}" + (f" {variant}" if variant else "")
            tag = "_".join(w for w in (m, *variant.replace("-", "").split()) if w != "on")
            got, took = run_process(video, out / "frames" / f"{name}_{tag}", None, m, data=data,
                                    extra_args=("--pose", name, *extra))
            row[label] = {**score(got, inputs, truths, bg, scored), "seconds": round(took, 1)}
            panels = [[(f"input yaw {head_pose(i)[0]:+.0f}", inputs[i]["image"]), (f"{label} {name}", got[i]),
                       ("ground truth", truths[i]["image"]), ("2D homography", homog[i])] for i in rows]
            cv2.imwrite(str(out / f"crops_{name.replace('=', '_')}_{tag}.png"), side_by_side(panels, [box] * len(rows)))
        results[name] = row
        print(name, {k: (round(v["psnr"], 2), round(v["ssim"], 3)) for k, v in row.items()}, flush=True)
    methods = list(next(iter(results.values()), {}))
    lines = ["| offset | " + " | ".join(methods) + " |", "| --- |" + " --- |" * len(methods)]
    for name, row in results.items():
        lines.append(f"| {name} | " + " | ".join(f"{row[k]['psnr']:.2f} dB / {row[k]['ssim']:.3f}" for k in methods) + " |")
    table = "\n".join(lines)
    real = {v: real_face_camera(data, v, args.real_frames, out, [FACE_CAMERA_LIMIT_DEG, 45.0]) for v in args.real_videos}
    lines = ["| video | " + " | ".join(next(iter(real.values()), {})) + " |", "| --- |" + " --- |" * 3]
    lines += [f"| {v} | " + " | ".join(f"{y:.1f} / {p:.1f}" for y, p in row.values()) + " |" for v, row in real.items()]
    real_table = "\n".join(lines) if real else ""
    (out / "results.md").write_text(f"PSNR / SSIM over the head region, frames {args.skip}-{args.frames - 1}\n\n{table}\n\n"
                                    f"--face-camera 1: mean |yaw| / |pitch| (degrees) still needed to look into the "
                                    f"camera, refitted\n\n{real_table}\n")
    (out / "results.json").write_text(json.dumps({"synthetic": results, "face_camera": real}, indent=1))
    print(table)
    print(real_table)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
