"""Landmark corrections over real video: does a corrected point stay on its facial feature?

On each shared video (../shared/data/video, or $FACESCULPT_DATA) the landmark network runs on every
frame; on the first frame where the uncorrected fit sits still on the left nostril (iBUG 33, within
0.5 % of the inter-ocular distance, else frame 30), landmark 34 (nose base, centre) is corrected onto
where the network sees 33 (``--pair 34 33``; e.g. ``--pair 20 19`` for a brow, ``--pair 52 51`` for
the upper lip), and from then on the fitter uses the correction in every frame, as the fitter node
does (closed loop). Per frame, the distance from the correction's target to the network's 33, in %
of the inter-ocular distance (outer eye corners): median, 90th percentile and max, for each model
and each head frame the correction can be kept in:

* ``detected``: a rigid reference (the nose and eyes of the fit it was made on) posed on each
  frame's detected points (:class:`LandmarkCorrections` given the points, as the node does);
* ``detected-1``: the same with the network's own point for the feature (33) left out of the points
  the correction sees, so the reference cannot lean on the very point it is judged against;
* ``fit``: the pose of the face's latest fit, which the correction itself pulls;
* ``open``: the pose of this frame's fit, which never sees the correction (no feedback; what a
  measurement that does not feed the correction back sees, as tests/test_landmark_corrections.py
  did before the ``detected`` head frame).

Also printed: the fitted landmark 34 itself (where the model put the corrected point), the range of
yaw while the correction was kept (degrees), and the time of the targets per frame (ms) beside the
fit's. The network's 33 is the reference here, and the ``detected`` head frame is posed on the same
network's nose and eyes (33 among them; ``detected-1`` shows what that is worth).

Run: ``python -m benchmarks.bench_corrections [--videos d3 d0 d12] [--frames N] [--pair 34 33]``.
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from facesculpt.geometry import to_ibug68
from facesculpt.geometry.ibug68 import IBUG68_FROM_MESH
from facesculpt.nodes.camera.intrinsics import intrinsics_from_fov
from facesculpt.nodes.fitter import FitterConfig, load_model, make_fitter
from facesculpt.nodes.fitter.corrections import LandmarkCorrections, fit_id, ibug68_points
from facesculpt.nodes.fitter.stage import fit_landmarks
from facesculpt.nodes.landmarks import LandmarkDetector
from facesculpt.paths import shared_data_dir


def detect(path, frames: int | None):
    """(points per frame: (468, 3) px or None, (w, h), fps) of a video."""
    cap = cv2.VideoCapture(str(path))
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
    detector, out, size = LandmarkDetector(), [], (0, 0)
    while frames is None or len(out) < frames:
        ok, frame = cap.read()
        if not ok:
            break
        size = frame.shape[1::-1]
        faces = detector.track(frame)
        out.append(faces[0].points if faces else None)
    cap.release()
    return out, size, fps


def follow(points_per_frame, size, fps, model, head_frame: str, pair=(34, 33)) -> dict:
    """The correction's target and the fitted landmark ``pair[0]`` against the network's ``pair[1]``
    (fractions of the inter-ocular distance per frame), the yaw (degrees) and times (ms) while it
    was kept."""
    corrected, feature = pair[0] - 1, pair[1] - 1
    w, h = size
    fitter = make_fitter(model, FitterConfig(), (w, h), intrinsics_from_fov(w, h, 60.0))
    corrections, last = LandmarkCorrections(), None
    landmark = fit_id(pair[0], model.dense)
    out = {"target": [], "fitted": [], "yaw": [], "targets_ms": [], "fit_ms": []}
    for i, points in enumerate(points_per_frame):
        if points is None:
            continue
        seen = to_ibug68(points)
        given = points if head_frame.startswith("detected") else None
        if head_frame == "detected-1":
            given = points.copy()
            given[IBUG68_FROM_MESH[feature]] = np.nan
        t0 = time.perf_counter()
        targets = corrections.targets(last, given) if len(corrections) else None
        t1 = time.perf_counter()
        fit = fit_landmarks(fitter, points[None], [1.0], i / fps, 0.5, None if head_frame == "open" else targets).fit
        t2 = time.perf_counter()
        if fit is None:
            continue
        iod = np.linalg.norm(seen[36] - seen[45])
        fitted = ibug68_points(fit, model.dense)
        if len(corrections):
            if head_frame == "open":  # by this frame's own (uncorrected) fit
                targets = corrections.targets(fit)
            out["target"].append(np.linalg.norm(targets[landmark] - seen[feature]) / iod)
            out["fitted"].append(np.linalg.norm(fitted[corrected] - seen[feature]) / iod)
            out["yaw"].append(fit.yaw_pitch_roll[0])
            out["targets_ms"].append((t1 - t0) * 1e3)
            out["fit_ms"].append((t2 - t1) * 1e3)
        elif i == 30 or (i < 30 and np.linalg.norm(fitted[feature] - seen[feature]) < 0.005 * iod):
            corrections.set(landmark, seen[feature], fit, model, given)
        last = fit
    return out


def spread(values) -> str:
    v = 100 * np.asarray(values)
    return f"{np.median(v):5.2f} {np.percentile(v, 90):5.2f} {v.max():5.2f}" if len(v) else "   -     -     -"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--videos", nargs="+", default=["d3", "d0", "d12"])
    parser.add_argument("--frames", type=int, default=None, help="the first N frames of each (default: all)")
    parser.add_argument("--pair", type=int, nargs=2, default=(34, 33), metavar=("CORRECTED", "ONTO"),
                        help="iBUG numbers: the landmark corrected and the one whose detected point it is put on")
    args = parser.parse_args()
    data = shared_data_dir()
    if data is None:
        raise SystemExit("no shared data (set FACESCULPT_DATA or place it at ../shared/data)")
    models = {name: load_model(name) for name in ("facemesh", "sfm")}
    print("% of the inter-ocular distance: median p90 max; yaw range while kept, degrees; ms per frame")
    print(f"{'video':6} {'model':9} {'head frame':10} {'frames':>6} {'target':>17} {'fitted 34':>17} {'yaw':>5} "
          f"{'targets':>8} {'fit':>6}")
    for video in args.videos:
        points, size, fps = detect(data / "video" / f"{video}.mp4", args.frames)
        for name, model in models.items():
            for head_frame in ("detected", "detected-1", "fit", "open"):
                r = follow(points, size, fps, model, head_frame, tuple(args.pair))
                yaw = np.ptp(r["yaw"]) if r["yaw"] else 0.0
                print(f"{video:6} {name:9} {head_frame:10} {len(r['target']):6d} {spread(r['target']):>17} "
                      f"{spread(r['fitted']):>17} {yaw:5.1f} {np.mean(r['targets_ms'] or [0]):8.3f} "
                      f"{np.mean(r['fit_ms'] or [0]):6.2f}", flush=True)


if __name__ == "__main__":
    main()
