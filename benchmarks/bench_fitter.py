"""Fitter benchmark: accuracy and time per fit against eos-py in the same run.

1. Synthetic ground truth from the Surrey Face Model (``--faces`` faces, default 200): alpha uniform
   in ±2 sigma over all 63 components, each blendshape weight uniform in [0, 0.5], yaw ±60°,
   pitch ±20°, roll ±10°, scaled orthographic camera (eos' camera model), 1 px landmark noise, 68
   iBUG landmarks with the outline points on the true outline of the posed face
   (tests/synthetic_faces.py). For our fitter and eos' ``fit_shape_and_pose`` (same
   model, blendshapes, contours, landmark mapping, 5 iterations): mean 3D vertex error after
   similarity alignment (mm), landmark reprojection error (px), time per fit — by |yaw| bin.
2. Paper Table 1 analogue: with / without the ray-triangle outline refinement (nearest vertex),
   frontal vs yaw 45°, time and error.
3. Perspective ground truth: the same faces through a pinhole camera, fitted with and without K.
4. Facemesh dense fit time per frame (needs `facesculpt setup` for the tessellation; synthetic
   468-point observations from the model's neutral), and the paper's 20.63 / 30.58 ms.
5. Real video (needs `facesculpt setup`): the landmark networks on every frame of
   ../shared/data/video/*.mp4; the SFM fitted to their iBUG-68 mapping (reprojection RMSE of the
   68 landmarks per frame, px) and the facemesh dense fit (its residual: RMS distance of the points
   from the rigidly posed neutral, px), with time per fit for both.

Run: ``python -m benchmarks.bench_fitter [--faces 200]``. BLAS is limited to one thread (eos runs
single-threaded; tiny matrices gain nothing from threads).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import sys
import time

import numpy as np

from benchmarks.eos_peer import EosPeer
from benchmarks.synthetic_faces import (
    landmark_reprojection_error,
    make_face,
    similarity_aligned_error,
)
from facesculpt.nodes.fitter import FitterConfig, load_model, make_fitter
from facesculpt.nodes.fitter.eos_import import sfm_files
from facesculpt.paths import shared_data_dir

BINS = [(0, 20), (20, 40), (40, 61)]
PAPER_MS = (20.63, 30.58)


def timed(fn, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    return out, (time.perf_counter() - t0) * 1e3


def fit_all(fitter, faces, model):
    """Fit each synthetic face from scratch: (3D errors mm, reprojection errors px, times ms)."""
    errs, reps, times = [], [], []
    for f in faces:
        fitter.reset()
        r, ms = timed(fitter.fit, f.noisy, f.ids)
        errs.append(similarity_aligned_error(r.model_vertices, f.vertices))
        reps.append(landmark_reprojection_error(r.projected, model, f.ids, f.noisy))
        times.append(ms)
    return errs, reps, times


def compare_with_eos(model, files, n_faces: int, seed: int = 0, iterations: int = 5):
    rng = np.random.default_rng(seed)
    faces = [make_face(model, rng) for _ in range(n_faces)]
    fitter = make_fitter(model, FitterConfig(iterations=iterations, smoothing=False, accumulate_identity=False), (640, 480))
    try:
        peer = EosPeer(files, (640, 480), iterations)
    except ImportError:
        peer = None
    rows = []
    for f in faces:
        fitter.reset()
        r, ms = timed(fitter.fit, f.noisy, f.ids)
        row = dict(yaw=abs(f.yaw), err=similarity_aligned_error(r.model_vertices, f.vertices),
                   rep=landmark_reprojection_error(r.projected, model, f.ids, f.noisy), ms=ms)
        if peer is not None:
            (V, P), ems = timed(peer.fit, f.noisy, f.ids)
            row.update(eos_err=similarity_aligned_error(V.astype(np.float32), f.vertices),
                       eos_rep=landmark_reprojection_error(P, model, f.ids, f.noisy), eos_ms=ms and ems)
        rows.append(row)
    return rows, peer is not None


def table(rows, has_eos: bool) -> str:
    head = "| abs(yaw) | n | 3D err ours (mm) | 3D err eos (mm) | reproj ours (px) | reproj eos (px) | ms ours | ms eos | time ratio eos/ours |"
    lines = [head, "|" + "---|" * 9]
    for lo, hi in BINS + [(0, 61)]:
        sel = [r for r in rows if lo <= r["yaw"] < hi]
        if not sel:
            continue
        g = lambda k: np.mean([r[k] for r in sel]) if has_eos or not k.startswith("eos") else float("nan")  # noqa: E731
        med = lambda k: np.median([r[k] for r in sel]) if has_eos or not k.startswith("eos") else float("nan")  # noqa: E731
        label = "all" if (lo, hi) == (0, 61) else f"{lo}-{min(hi, 60)}°"
        lines.append(
            f"| {label} | {len(sel)} | {g('err'):.2f} | {g('eos_err'):.2f} | {g('rep'):.2f} | {g('eos_rep'):.2f} | "
            f"{med('ms'):.1f} | {med('eos_ms'):.1f} | {med('eos_ms') / med('ms'):.1f}x |"
        )
    return "\n".join(lines)


def table1(model, n: int = 40, seed: int = 7) -> str:
    """Ray-triangle outline correspondences vs nearest vertex (and none), frontal vs yaw 45°."""
    lines = ["| outline | yaw | 3D err (mm) | reproj (px) | ms per fit |", "|---|---|---|---|---|"]
    for yaw in (0.0, 45.0):
        rng = np.random.default_rng(seed)
        faces = [make_face(model, rng, yaw=yaw * (1 if i % 2 else -1), pitch=0.0, roll=0.0) for i in range(n)]
        for mode in ("ray", "nearest", "off"):
            fitter = make_fitter(model, FitterConfig(outline=mode, smoothing=False, accumulate_identity=False), (640, 480))
            errs, reps, times = fit_all(fitter, faces, model)
            lines.append(f"| {mode} | {yaw:.0f}° | {np.mean(errs):.2f} | {np.mean(reps):.2f} | {np.median(times):.1f} |")
    return "\n".join(lines)


def perspective_table(model, files, n: int = 60, seed: int = 5) -> str:
    """Faces seen through a pinhole camera (f = 700 px, 640x480, head 450-650 mm away): our fitter
    with K (perspective) and without (scaled orthographic), and eos (scaled orthographic)."""
    K = np.array([[700.0, 0, 320], [0, 700.0, 240], [0, 0, 1]])
    rng = np.random.default_rng(seed)
    faces = [make_face(model, rng, K=K, distance_mm=float(rng.uniform(450, 650))) for _ in range(n)]
    config = FitterConfig(smoothing=False, accumulate_identity=False)
    fitters = {"ours, perspective K": make_fitter(model, config, (640, 480), K),
               "ours, orthographic": make_fitter(model, config, (640, 480))}
    try:
        peer = EosPeer(files, (640, 480), 5)
    except ImportError:
        peer = None
    lines = ["| fitter | 3D err (mm) | reproj (px) | ms per fit |", "|---|---|---|---|"]
    for name, fitter in fitters.items():
        errs, reps, times = fit_all(fitter, faces, model)
        lines.append(f"| {name} | {np.mean(errs):.2f} | {np.mean(reps):.2f} | {np.median(times):.1f} |")
    if peer is not None:
        errs, reps, times = [], [], []
        for f in faces:
            (V, P), ms = timed(peer.fit, f.noisy, f.ids)
            errs.append(similarity_aligned_error(V.astype(np.float32), f.vertices))
            reps.append(landmark_reprojection_error(P, model, f.ids, f.noisy))
            times.append(ms)
        lines.append(f"| eos-py, orthographic | {np.mean(errs):.2f} | {np.mean(reps):.2f} | {np.median(times):.1f} |")
    return "\n".join(lines)


def dense_timing(frames: int = 200) -> str:
    from facesculpt.nodes.fitter.pose import rotation_from_euler
    from facesculpt.paths import MissingModelsError

    try:
        model = load_model("facemesh")
    except MissingModelsError as exc:
        return f"facemesh dense: skipped ({exc})"
    rng = np.random.default_rng(3)
    K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
    fitter = make_fitter(model, FitterConfig(), (640, 480), K)
    times = []
    for i in range(frames):
        R = rotation_from_euler(30 * np.sin(i / 20), 10 * np.sin(i / 33), 0)
        s = 2.0
        pts = s * model.mean @ R.T + [320, 240, 0] + rng.normal(0, 1.0, (len(model.mean), 3))
        _, ms = timed(fitter.fit, pts, None, None, i / 30)
        times.append(ms)
    return f"facemesh dense ({frames} frames, 468 points, perspective K): median {np.median(times):.2f} ms per fit"


def real_video(model, max_frames: int = 400) -> str:
    import cv2

    from facesculpt.paths import MissingModelsError

    try:
        from facesculpt.geometry import to_ibug68
        from facesculpt.nodes.landmarks import LandmarkDetector

        detector = LandmarkDetector()
    except (ImportError, MissingModelsError) as exc:
        return f"real video: skipped ({exc})"
    lines = ["| video | frames fitted | SFM RMSE px median / p90 | SFM ms | dense residual px median / p90 | dense ms |",
             "|---|---|---|---|---|---|"]
    for path in sorted((shared_data_dir() / "video").glob("*.mp4")):
        cap = cv2.VideoCapture(str(path))
        W, H = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
        sparse = make_fitter(model, FitterConfig(), (W, H))
        dense = make_fitter("facemesh", FitterConfig(), (W, H))
        detector.reset()
        rmse, res, t_s, t_d = [], [], [], []
        i = 0
        while i < max_frames:
            ok, frame = cap.read()
            if not ok:
                break
            faces = detector.track(frame)
            if faces:
                pts = np.asarray(faces[0].points, np.float64)
                r, ms = timed(sparse.fit, to_ibug68(pts), None, None, i / fps)
                rmse.append(r.residual_px)
                t_s.append(ms)
                r, ms = timed(dense.fit, pts, None, None, i / fps)
                res.append(r.residual_px)
                t_d.append(ms)
            i += 1
        cap.release()
        lines.append(f"| {path.name} ({W}x{H}) | {len(rmse)}/{i} | {np.median(rmse):.2f} / {np.percentile(rmse, 90):.2f} | "
                     f"{np.median(t_s):.1f} | {np.median(res):.2f} / {np.percentile(res, 90):.2f} | {np.median(t_d):.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--faces", type=int, default=200)
    ap.add_argument("--iterations", type=int, default=5)
    args = ap.parse_args(argv)
    if shared_data_dir() is None:
        print("shared data not found (FACESCULPT_DATA or ../shared/data): nothing to benchmark")
        return 0
    model = load_model("sfm")
    files = sfm_files()
    rows, has_eos = compare_with_eos(model, files, args.faces, iterations=args.iterations)
    print(f"## Synthetic SFM faces: ours vs eos-py fit_shape_and_pose ({args.faces} faces, {args.iterations} iterations)")
    if not has_eos:
        print("(eos-py not installed: eos columns are NaN)")
    print(table(rows, has_eos))
    print(f"\npaper (i7-3770, CUDA-accelerated): {PAPER_MS[0]} ms frontal / {PAPER_MS[1]} ms oblique")
    print("\n## Outline correspondences (paper Table 1 analogue, 40 faces each)")
    print(table1(model))
    print("\n## Perspective ground truth (60 faces)")
    print(perspective_table(model, files))
    print("\n## " + dense_timing())
    print("\n## Real video: landmark networks -> fitter (SFM via iBUG-68, 5 iterations; facemesh dense)")
    print(real_video(model))
    return 0


if __name__ == "__main__":
    sys.exit(main())
