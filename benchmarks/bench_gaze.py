"""Gaze against ground truth on the synthetic head, and the gaze of the shared real videos (issue 48).

    python -m benchmarks.bench_gaze [--frames 150] [--seeds 7 11] [--videos d0 d3 d12 s18]
        [--max-frames N] [--out /tmp/bench_gaze] [--verbose]

**Synthetic.** The realism benchmark's head (:mod:`benchmarks.realism.scene`: the Surrey Face Model,
a random identity per seed, textured from a real face, turning yaw ±25°, pitch ±10° over a real
background, 640x480, 60° field of view) with eyeballs of its own (:mod:`benchmarks.realism.eyeballs`).
Both eyes fixate a point 600 mm out along a gaze direction that moves in the head by saccades
between random fixations (yaw and pitch in ±20°, a new one every 8-16 frames, two frames to move),
so the eyes converge as real ones do. The frames go through ``Pipeline(gaze=True)`` (the face-mesh
model, the iris network, :mod:`facesculpt.nodes.fitter.gaze`). Measured: the angle between the
combined gaze ray and the true direction from between the eyeballs to the fixated point (mean,
median, share of frames over 8°), each eye's error, over the frames after the eyeballs are learned
and over all frames; the cost of the irises and the gaze as a ratio to the face-mesh network's own
time (process CPU time, the same frames, this run).

**Real.** The shared videos through the same pipeline: the angle between the two eyes' rays while
both are open (median; the vergence of eyes fixating the camera at the fitted distance beside it),
the frames flagged as blinks, and the jitter of the combined gaze (the median frame-to-frame change
of its yaw and pitch, degrees). Pictures in ``--out``: eye crops with the estimated rays (green,
a closed eye orange) and, on the synthetic frames, the true direction (red).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np

from benchmarks.realism.eyeballs import draw_eyes, eye_anatomy
from benchmarks.realism.raster import render_textured
from benchmarks.realism.scene import make_scene, rotation
from facesculpt.paths import shared_data_dir

FIXATION_MM = 600.0
GAZE_LIMIT_DEG = 20.0


def gaze_schedule(frames: int, seed: int) -> np.ndarray:
    """(frames, 2) the gaze's yaw, pitch in the head (degrees): fixations held 8-16 frames, two
    frames of saccade between them."""
    rng = np.random.default_rng(seed)
    out = np.zeros((frames, 2))
    current = rng.uniform(-GAZE_LIMIT_DEG, GAZE_LIMIT_DEG, 2)
    i = 0
    while i < frames:
        target = rng.uniform(-GAZE_LIMIT_DEG, GAZE_LIMIT_DEG, 2)
        hold = int(rng.integers(8, 17))
        for k in range(hold):
            if i + k < frames:
                out[i + k] = current + (target - current) * min((k + 1) / 2.0, 1.0)
        current, i = target, i + hold
    return out


def eye_truth(eyes, yaw_pitch: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For a gaze (yaw, pitch) in the head: each eye's (yaw, pitch) in the head (2, 2) fixating
    the point FIXATION_MM out from between the eyeballs, that point (3,) and the combined unit
    direction (3,), model space."""
    from benchmarks.realism.eyeballs import eye_rotation

    mid = eyes.centres.mean(axis=0)
    d = eye_rotation(*yaw_pitch) @ np.array([0.0, 0.0, 1.0])
    target = mid + FIXATION_MM * d
    angles = np.zeros((2, 2))
    for e in (0, 1):
        v = target - eyes.centres[e]
        v /= np.linalg.norm(v)
        angles[e] = np.degrees([np.arctan2(v[0], v[2]), np.arctan2(v[1], np.hypot(v[0], v[2]))])
    return angles, target, d


def render_sequence(scene, eyes, schedule: np.ndarray) -> tuple[list, list]:
    """The frames (uint8 BGR) and per frame the truth: camera-space combined direction (3,), each
    eye's direction (2, 3)."""
    from benchmarks.realism.eyeballs import eye_rotation

    frames, truths = [], []
    for i in range(len(schedule)):
        yaw, pitch, t = scene.pose(i)
        from benchmarks.realism.scene import FACING, PIVOT

        R = rotation(yaw, pitch) @ FACING
        to_camera = lambda V, R=R, t=t: (np.asarray(V, np.float64) - PIVOT) @ R.T + t  # noqa: E731
        angles, _, d = eye_truth(eyes, schedule[i])
        img = render_textured(scene.K, to_camera(scene.rest), scene.triangles, scene.texcoords, scene.alpha,
                              scene.texture, scene.background)
        img = draw_eyes(img, scene, eyes, R, to_camera, angles)
        frames.append(np.clip(img + 0.5, 0, 255).astype(np.uint8))
        eye_dirs = np.stack([R @ (eye_rotation(*angles[e]) @ [0.0, 0.0, 1.0]) for e in (0, 1)])
        truths.append((R @ d, eye_dirs))
    return frames, truths


def eye_crop(frame: np.ndarray, gaze, K: np.ndarray, truth: np.ndarray | None = None, size=(360, 150)) -> np.ndarray:
    """The frame's eye region with the estimated rays drawn (green; a closed eye orange) and, when
    given, the true combined direction from between the eyes (red), scaled to ``size`` (W, H)."""
    from facesculpt.nodes.renderer.gaze_overlay import draw_gaze

    out = draw_gaze(frame, K, gaze.centres, gaze.directions, gaze.closed)
    if truth is not None:
        front = gaze.centres.mean(axis=0) + 12 * truth
        a = (K @ (front / front[2]))[:2]
        b = a + K[0, 0] * 80 / front[2] * truth[:2]  # as draw_gaze draws a ray
        cv2.line(out, tuple(int(round(v)) for v in a), tuple(int(round(v)) for v in b), (40, 40, 230), 1, cv2.LINE_AA)
    centre = (K @ (gaze.centres.mean(axis=0) / gaze.centres.mean(axis=0)[2]))[:2]
    half = 1.6 * np.linalg.norm((K @ (gaze.centres[0] / gaze.centres[0][2]))[:2] - (K @ (gaze.centres[1] / gaze.centres[1][2]))[:2])
    x0, y0 = int(max(centre[0] - half, 0)), int(max(centre[1] - half * 0.42, 0))
    crop = out[y0:int(centre[1] + half * 0.42), x0:int(centre[0] + half)]
    return cv2.resize(crop, size, interpolation=cv2.INTER_CUBIC) if crop.size else np.zeros((size[1], size[0], 3), np.uint8)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def run_pipeline(frames: list, fps: float = 25.0) -> tuple[list, dict]:
    """Each frame's first fit's gaze (None without a fit) and the CPU time (s) of the face mesh
    network, the irises and the gaze over the frames."""
    from facesculpt.app.pipeline import Pipeline

    gazes, cpu = [], {"mesh": 0.0, "irises": 0.0, "gaze": 0.0}
    with Pipeline(gaze=True) as p:
        mesh_run = p.detector.mesh_net.run

        def timed_mesh(x):
            t0 = time.process_time()
            out = mesh_run(x)
            cpu["mesh"] += time.process_time() - t0
            return out

        p.detector.mesh_net.run = timed_mesh
        iris_find = p.irises.find

        def timed_irises(image, points):
            t0 = time.process_time()
            out = iris_find(image, points)
            cpu["irises"] += time.process_time() - t0
            return out

        p.irises.find = timed_irises
        import facesculpt.app.pipeline as pipeline_module

        estimate = pipeline_module.estimate_gaze

        def timed_gaze(*a):
            t0 = time.process_time()
            out = estimate(*a)
            cpu["gaze"] += time.process_time() - t0
            return out

        pipeline_module.estimate_gaze = timed_gaze
        try:
            for i, f in enumerate(frames):
                fits, _ = p.analyse(f, i / fps)
                gazes.append(fits[min(fits)].gaze if fits else None)
        finally:
            pipeline_module.estimate_gaze = estimate
    return gazes, cpu


def synthetic(args, data: Path) -> dict:
    results = {}
    for seed in args.seeds:
        t0 = time.perf_counter()
        cache = args.out / f"synthetic_{seed}_{args.frames}.npz"
        if cache.is_file():  # the same seed and length render the same frames
            stored = np.load(cache)
            frames, schedule = list(stored["frames"]), stored["schedule"]
            truths = list(zip(stored["truth"], stored["eye_truths"]))
        else:
            scene = make_scene(data, frames=args.frames, seed=seed)
            eyes = eye_anatomy(scene, seed)
            schedule = gaze_schedule(args.frames, seed)
            frames, truths = render_sequence(scene, eyes, schedule)
            np.savez(cache, frames=np.stack(frames), schedule=schedule, truth=np.stack([t[0] for t in truths]),
                     eye_truths=np.stack([t[1] for t in truths]))
        print(f"seed {seed}: {len(frames)} frames in {time.perf_counter() - t0:.0f} s", flush=True)
        if args.out:
            cv2.imwrite(str(args.out / f"synthetic_{seed}_frame.png"), np.hstack([frames[5], frames[20]]))
        gazes, cpu = run_pipeline(frames)
        from benchmarks.realism.scene import intrinsics

        K = intrinsics()
        shown = [i for i in range(40, len(frames), max(1, (len(frames) - 40) // 8))][:8]
        tiles = [eye_crop(frames[i], gazes[i], K, truths[i][0]) for i in shown if gazes[i] is not None]
        if tiles:
            cv2.imwrite(str(args.out / f"synthetic_{seed}_eyes.png"),
                        np.vstack([np.hstack(tiles[k:k + 2]) for k in range(0, len(tiles) - 1, 2)]))
        rows = []
        for i, (g, (truth, eye_truths)) in enumerate(zip(gazes, truths)):
            if g is None or not np.all(np.isfinite(g.direction)):
                rows.append((i, np.nan, np.nan, np.nan, 0))
                continue
            rows.append((i, angle_deg(g.direction, truth), angle_deg(g.directions[0], eye_truths[0]),
                         angle_deg(g.directions[1], eye_truths[1]), int(g.learned)))
            if args.verbose:
                from facesculpt.nodes.fitter.gaze import yaw_pitch

                print(i, "camera yaw/pitch est", np.round([g.yaw_deg, g.pitch_deg], 1), "true",
                      np.round(yaw_pitch(truth), 1), "eyes est", np.round(g.eye_angles.ravel(), 1), "true",
                      np.round(yaw_pitch(eye_truths).ravel(), 1), "schedule", np.round(schedule[i], 1))
        a = np.array(rows, float)
        learned = a[a[:, 4] == 1]
        results[str(seed)] = {
            "frames": len(a), "with gaze": int(np.isfinite(a[:, 1]).sum()),
            "learned frames": len(learned),
            "mean error deg": float(np.nanmean(learned[:, 1])),
            "median error deg": float(np.nanmedian(learned[:, 1])),
            "share over 8 deg": float(np.mean(np.nan_to_num(learned[:, 1], nan=180.0) > 8.0)),
            "right eye mean deg": float(np.nanmean(learned[:, 2])),
            "left eye mean deg": float(np.nanmean(learned[:, 3])),
            "all frames mean deg": float(np.nanmean(a[:, 1])),
            "irises / mesh network cpu": cpu["irises"] / cpu["mesh"],
            "gaze / mesh network cpu": cpu["gaze"] / cpu["mesh"],
            "irises + gaze / mesh network cpu": (cpu["irises"] + cpu["gaze"]) / cpu["mesh"],
        }
        print(seed, json.dumps(results[str(seed)], indent=1), flush=True)
    return results


def real(args, data: Path) -> dict:
    from facesculpt.app.pipeline import Pipeline

    results = {}
    for name in args.videos:
        cap = cv2.VideoCapture(str(data / "video" / f"{name}.mp4"))
        fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
        rows, tiles = [], []
        with Pipeline(gaze=True) as p:
            i = 0
            while True:
                ok, frame = cap.read()
                if not ok or (args.max_frames and i >= args.max_frames):
                    break
                fits, _ = p.analyse(frame, i / fps)
                g = fits[min(fits)].gaze if fits else None
                if g is not None and i % 45 == 20 and len(tiles) < 6:
                    tiles.append(eye_crop(frame, g, p.K))
                if g is not None:
                    both = not g.closed.any()
                    spread = angle_deg(g.directions[0], g.directions[1]) if both else np.nan
                    half = np.linalg.norm(g.centres[0] - g.centres[1]) / 2.0
                    camera_vergence = float(np.degrees(2 * np.arctan2(half, np.linalg.norm(g.origin))))
                    rows.append((i, spread, camera_vergence, g.blink, g.closed.any(), g.yaw_deg, g.pitch_deg,
                                 int(g.learned)))
                i += 1
        if tiles:
            cv2.imwrite(str(args.out / f"real_{name}_eyes.png"),
                        np.vstack([np.hstack(tiles[k:k + 2]) for k in range(0, len(tiles) - 1, 2)]))
        a = np.array(rows, float)
        steps = np.abs(np.diff(a[:, 5:7], axis=0))
        consecutive = np.diff(a[:, 0]) == 1
        steps = steps[consecutive & np.all(np.isfinite(steps), axis=1)]
        results[name] = {
            "frames": i, "with gaze": len(a),
            "median angle between the eyes' rays deg": float(np.nanmedian(a[:, 1])),
            "median vergence fixating the camera deg": float(np.median(a[:, 2])),
            "median |rays' angle - camera vergence| deg": float(np.nanmedian(np.abs(a[:, 1] - a[:, 2]))),
            "frames with both eyes closed": int(a[:, 3].sum()),
            "frames with an eye closed": int(a[:, 4].sum()),
            "jitter: median |d yaw| deg": float(np.median(steps[:, 0])) if len(steps) else np.nan,
            "jitter: median |d pitch| deg": float(np.median(steps[:, 1])) if len(steps) else np.nan,
        }
        print(name, json.dumps(results[name], indent=1), flush=True)
    return results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--seeds", type=int, nargs="*", default=[7, 11])
    ap.add_argument("--videos", nargs="*", default=["d0", "d3", "d12", "s18"])
    ap.add_argument("--max-frames", type=int, default=0, help="at most this many frames of each video (0: all)")
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_gaze"),
                    help="where gaze.json, the pictures and the rendered frames (kept for a rerun) go")
    ap.add_argument("--verbose", action="store_true", help="print each synthetic frame's estimate and truth")
    args = ap.parse_args(argv)
    data = shared_data_dir()
    if data is None:
        print("bench_gaze: the shared data folder is missing (set FACESCULPT_DATA)")
        return 1
    args.out.mkdir(parents=True, exist_ok=True)
    results = {"synthetic": synthetic(args, data) if args.seeds else {},
               "real": real(args, data) if args.videos else {}}
    (args.out / "gaze.json").write_text(json.dumps(results, indent=1))
    print("wrote", args.out / "gaze.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
