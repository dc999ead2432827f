"""Landmark time per frame at 856x480: onnxruntime (the converted networks) next to
ai-edge-litert running the original .tflite networks, through the same pipeline, in the same run.

    python -m benchmarks.bench_landmarks [--video s18] [--frames 120] [--threads 1] [--json out.json]

Frames: the shared video (default s18.mp4, 1280x720) resized to 856x480, the paper's size.
Measured per frame, interleaving the two runtimes frame by frame:
  detection frame  ``detect()``: detector on the whole frame (+ tiles), mesh twice on the face
  tracking frame   ``track()``: mesh once on the crop from the last points
and each network alone on one input. Reported: medians (ms), the ratio onnxruntime / litert
(target <= 1.2), and the paper's 36.28 ms for landmark detection (i7-3770 + GTX TITAN).
"""

from __future__ import annotations

import sys

import numpy as np

from benchmarks.renderer_scene import read_frames
from benchmarks.runtime_pair import BACKENDS, report, runtime_arguments, timed
from facesculpt.nodes.landmarks.detector import LandmarkDetector

PAPER_MS = 36.28


def _arguments(parser):
    parser.add_argument("--video", default="s18", help="shared video name (default s18)")
    parser.add_argument("--frames", type=int, default=120)


def main(argv=None) -> int:
    args, data, models = runtime_arguments(__doc__, _arguments, argv)
    if data is None:
        return 2
    frames = read_frames(data, args.video, args.frames, size=(856, 480))
    trackers = {b: LandmarkDetector(models, threads=args.threads, backend=b) for b in BACKENDS}
    detectors = {b: LandmarkDetector(models, threads=args.threads, backend=b) for b in BACKENDS}

    # Warm-up (first runs allocate), and the same result from both runtimes.
    for b in BACKENDS:
        for _ in range(3):
            detectors[b].detect(frames[0])
            trackers[b].track(frames[0])
    ref = {b: detectors[b].detect(frames[0]) for b in BACKENDS}
    if not all(ref.values()):
        print("no face in the first frame", file=sys.stderr)
        return 1
    agreement = float(np.abs(ref["onnxruntime"][0].points - ref["litert"][0].points).max())

    times = {f"{kind}/{b}": [] for kind in ("detect", "track", "detector_net", "mesh_net") for b in BACKENDS}
    x_det = np.random.default_rng(0).uniform(-1, 1, (1, 128, 128, 3)).astype(np.float32)
    x_mesh = np.random.default_rng(1).uniform(0, 1, (1, 192, 192, 3)).astype(np.float32)
    tracked = {b: 0 for b in BACKENDS}
    for i, frame in enumerate(frames):
        order = BACKENDS if i % 2 == 0 else BACKENDS[::-1]
        for b in order:
            times[f"track/{b}"].append(timed(trackers[b].track, frame))
            tracked[b] += bool(trackers[b]._tracks)
            times[f"detect/{b}"].append(timed(detectors[b].detect, frame))
            times[f"detector_net/{b}"].append(timed(detectors[b].detector_net.run, x_det))
            times[f"mesh_net/{b}"].append(timed(detectors[b].mesh_net.run, x_mesh))

    rows = [("detection frame (detect)", "detect"), ("tracking frame (track)", "track"),
            ("  detector network 128px", "detector_net"), ("  mesh network 192px", "mesh_net")]
    result = {"frames": len(frames), "threads": args.threads, "video": args.video, "paper_ms": PAPER_MS,
              "max_point_difference_px": agreement, "faces_tracked": tracked}
    med = report(f"landmarks at 856x480 ({args.video}.mp4, {len(frames)} frames), {args.threads} thread(s), "
                 f"median ms per call", rows, times, result, args.json)
    print(f"paper (landmark detection, i7-3770 + GTX TITAN): {PAPER_MS} ms; tracking frame here is "
          f"{PAPER_MS / med['track/onnxruntime']:.1f}x faster, detection frame "
          f"{PAPER_MS / med['detect/onnxruntime']:.1f}x")
    print(f"faces tracked: {tracked}; largest point difference between runtimes: {agreement:.4f} px")
    return 0


if __name__ == "__main__":
    sys.exit(main())
