"""The pose smoothing's lag against its jitter (issue 46): fitter settings compared on sequences
whose pose is known.

    python -m benchmarks.bench_pose_lag [--frames 60] [--still-frames 60] [--scenes 0,1,2,bench]
        [--variants before,default,...] [--oracle] [--out DIR]

Each variant (:data:`VARIANTS`: :class:`FitterConfig` fields changed from the defaults) fits the
Surrey model (``Pipeline``, default settings otherwise, as ``process`` fits) over

* the calibration sequences (:mod:`realism.calibration_scenes`: other identities, textures,
  backgrounds and motions than the benchmark's): what a setting is chosen on;
* the realism benchmark's turning head (:mod:`realism.scene`), untouched: reported only;
* the benchmark's head held nearly still (``motion="still"``, clean frames): the fitted pixels'
  jitter (:func:`realism.jitter.jitter`, px), the first ``STILL_SKIP_FRAMES`` left out.

Reported per sequence and variant: the rotation error (:func:`bench_registration.fitted_rotation`:
mean angle, pitch error mean / sd, r(pitch error, pitch), inner / outline vertices' px). Writes
``pose_lag.json`` and ``pose_lag.md`` to ``--out`` and prints the table. Needs the shared data
and ``facesculpt setup``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.bench_appearance import STILL_SKIP_FRAMES
from benchmarks.bench_registration import fitted_rotation, render
from benchmarks.realism.calibration_scenes import CALIBRATION_SCENES, make_calibration_scene
from benchmarks.realism.jitter import jitter
from benchmarks.realism.scene import FOV_DEG, make_scene
from facesculpt.paths import shared_data_dir

#: name -> FitterConfig fields changed from the defaults ("before": the smoothing as it was before
#: issue 46's options, one speed coefficient for rotation and expression, 0.05 Hz per mm/s, no
#: prediction; "default": the defaults as they are).
VARIANTS = {
    "before": {"smooth_beta_rotation": None, "smooth_beta_mm": 0.05},
    "default": {},
    "no smoothing": {"smoothing": False},
    "beta 2": {"smooth_beta": 2.0},
    "beta 5": {"smooth_beta": 5.0},
    "beta 5 beta_mm 0.2": {"smooth_beta": 5.0, "smooth_beta_mm": 0.2},
    "beta 5 beta_mm 0.5": {"smooth_beta": 5.0, "smooth_beta_mm": 0.5},
    "beta 10": {"smooth_beta": 10.0},
    "rotation 5": {"smooth_beta_rotation": 5.0},
    "predict": {"smooth_predict_rotation": 0.5, "smooth_predict_mm": 50.0},
    "predict rotation": {"smooth_predict_rotation": 0.5},
    "rotation 5 mm 0.1": {"smooth_beta_rotation": 5.0, "smooth_beta_mm": 0.1},
    "rotation 5 mm 0.2": {"smooth_beta_rotation": 5.0, "smooth_beta_mm": 0.2},
    "rotation 10 mm 0.2": {"smooth_beta_rotation": 10.0, "smooth_beta_mm": 0.2},
    "beta 10 beta_mm 0.2": {"smooth_beta": 10.0, "smooth_beta_mm": 0.2},
    "beta 20": {"smooth_beta": 20.0},
    "no rotation prior": {"rotation_prior_px": 0.0},
    "rotation prior 300": {"rotation_prior_px": 300.0},
    "rotation prior 1000": {"rotation_prior_px": 1000.0},
    "no identity accumulation": {"accumulate_identity": False},
    "outline off": {"outline": "off"},
    "no smoothing no rotation prior": {"smoothing": False, "rotation_prior_px": 0.0},
    "settle 30": {"rotation_prior_settle_frames": 30},
    "no relearn": {"rotation_prior_relearn_frames": 0},
    "no smoothing no rotation prior outline off": {"smoothing": False, "rotation_prior_px": 0.0, "outline": "off"},
}


#: --true-groups: which inner iBUG points (0-based) each name gives true ("inner": all of them).
TRUE_GROUPS = {"inner": range(17, 68), "brows": range(17, 27), "nose_bridge": range(27, 31),
               "nose_base": range(31, 36), "eyes": range(36, 48), "lips": range(48, 68)}


@contextlib.contextmanager
def true_points(scene, size: tuple[int, int], on: bool, group: str = "inner"):
    """With ``on``: every landmark detector of this process gives ``scene``'s true inner iBUG
    points of ``group`` (:data:`TRUE_GROUPS`; :mod:`realism.landmark_oracle`, KEEP 0; the other
    points, the jaw line and the network's depth stay the detector's), counted from this fit's
    first frame; the detector as it was afterwards."""
    from benchmarks.realism import landmark_oracle
    from facesculpt.nodes.landmarks.detector import LandmarkDetector

    saved = LandmarkDetector.track, LandmarkDetector.reset
    if on:
        truth = landmark_oracle.true_landmarks(scene)
        others = [k for k in range(truth.shape[1]) if k not in TRUE_GROUPS[group]]
        truth[:, others] = np.nan
        landmark_oracle.install(truth, size, 0.0)
    try:
        yield
    finally:
        LandmarkDetector.track, LandmarkDetector.reset = saved


def still_tracks(frames: list, config: dict) -> np.ndarray:
    """(F, V, 2) the SFM's fitted pixels over ``frames`` (25 frames/s) with the
    :class:`FitterConfig` fields ``config`` changed, up to the first frame without a fit."""
    import dataclasses

    from facesculpt.app.pipeline import Pipeline

    tracks = []
    with Pipeline("sfm", fov_deg=FOV_DEG) as pipe:
        pipe.fitter_config = dataclasses.replace(pipe.fitter_config, **config)
        for i, frame in enumerate(frames):
            fit = pipe.fit_frame(frame, i / 25.0)
            if fit is None:
                break
            tracks.append(np.asarray(fit.projected, np.float64))
    return np.array(tracks)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=60, help="frames of each moving sequence (25 fps)")
    p.add_argument("--still-frames", type=int, default=60, help="frames of the still head (0: none)")
    p.add_argument("--scenes", default="0,1,2,bench", help="calibration scene indices and/or 'bench'")
    p.add_argument("--variants", default=",".join(VARIANTS), help="names of VARIANTS, comma-separated")
    p.add_argument("--oracle", action="store_true",
                   help="the moving sequences fitted to their true inner points (the fitter's own error)")
    p.add_argument("--true-groups", default="",
                   help="also fit each sequence with only these groups' points true (names of TRUE_GROUPS, "
                        "comma-separated): which points carry an error")
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    data = shared_data_dir()
    if data is None:
        print("bench_pose_lag: the shared data folder is missing (../shared/data or FACESCULPT_DATA)", file=sys.stderr)
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_pose_lag_"))
    out.mkdir(parents=True, exist_ok=True)
    workers = max(1, min(4, len(os.sched_getaffinity(0))))
    variants = [v for v in args.variants.split(",") if v]
    results = {}
    # every scene is rendered before the first fit: the rendering processes fork, which a process
    # that runs the networks' threads must not do
    rendered = []
    for name in [s for s in args.scenes.split(",") if s]:
        scene = (make_scene(data, frames=args.frames) if name == "bench"
                 else make_calibration_scene(data, CALIBRATION_SCENES[int(name)], args.frames))
        rendered.append((name, scene, render(scene, workers)))
    if args.still_frames:
        still = make_scene(data, frames=args.still_frames, motion="still")
        still_frames = [t["image"] for t in render(still, workers)]
    for name, scene, truths in rendered:
        frames = [t["image"] for t in truths]
        label = ("benchmark (untouched)" if name == "bench" else f"calibration {name}") + (", true points" if args.oracle else "")
        size = (frames[0].shape[1], frames[0].shape[0])
        for v in variants:
            with true_points(scene, size, args.oracle):
                results.setdefault(label, {})[v] = fitted_rotation(scene, frames, truths, "sfm", config=VARIANTS[v])
            print(label, v, {k: round(x, 3) for k, x in results[label][v].items()}, flush=True)
            for g in [g for g in args.true_groups.split(",") if g]:
                with true_points(scene, size, True, g):
                    results[label][f"{v}, true {g}"] = fitted_rotation(scene, frames, truths, "sfm", config=VARIANTS[v])
                print(label, v, "true", g, {k: round(x, 3) for k, x in results[label][f"{v}, true {g}"].items()}, flush=True)
    if args.still_frames:
        for v in variants:
            tracks = still_tracks(still_frames, VARIANTS[v])
            results.setdefault("still head jitter px", {})[v] = float(jitter(tracks[STILL_SKIP_FRAMES:])[0])
            print("still", v, results["still head jitter px"][v], flush=True)
    lines = ["| sequence | variant | rotation error deg | pitch error mean / sd deg | r(pitch error, pitch) "
             "| r(yaw error, yaw) | inner px | outline px |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for label, rows in results.items():
        if label == "still head jitter px":
            continue
        for v, f in rows.items():
            lines.append(f"| {label} | {v} | {f['rotation_deg']:.2f} | {f['pitch_error_mean_deg']:+.2f} / "
                         f"{f['pitch_error_sd_deg']:.2f} | {f['r_pitch_error_pitch']:+.2f} | {f['r_yaw_error_yaw']:+.2f} "
                         f"| {f.get('inner_px', np.nan):.2f} | {f.get('outline_px', np.nan):.2f} |")
    if "still head jitter px" in results:
        base = results["still head jitter px"].get("before")
        lines += ["", "| still head (clean) | jitter px | / before |", "| --- | --- | --- |"]
        lines += [f"| {v} | {j:.4f} | {j / base if base else np.nan:.2f} |"
                  for v, j in results["still head jitter px"].items()]
    (out / "pose_lag.md").write_text("\n".join(lines) + "\n")
    (out / "pose_lag.json").write_text(json.dumps(results, indent=1))
    print("\n".join(lines))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
